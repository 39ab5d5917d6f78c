#!/usr/bin/env bash
# Renders every sample scene at the defaults (the whole method: trace, detect, relax, collapse,
# relax, render) into docs/gallery/SCENE.png, 400×400. Usage: tools/gallery.sh [STORED]
# (photons stored per scene, default 1e6). Builds the release binary first.
set -euo pipefail
cd "$(dirname "$0")/.."
stored="${1:-1e6}"
cargo build --release --quiet
bin=target/release/photonkit
mkdir -p docs/gallery target/gallery
for scene in samples/scenes/*.toml; do
  name=$(basename "$scene" .toml)
  SECONDS=0
  "$bin" --quiet pipeline "$scene" --stored "$stored" --out-dir "target/gallery/$name" -- --width 400 --height 400
  cp "target/gallery/$name/render.png" "docs/gallery/$name.png"
  printf '%-14s %4d s\n' "$name" "$SECONDS"
done
