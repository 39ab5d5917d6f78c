#!/usr/bin/env bash
# Detect (or relax) a photon map tile by tile on this machine: the same per-tile commands a
# cluster runs (tiles-slurm.sh, detect-k8s.yaml), JOBS at a time with xargs -P, then the merge.
#
#   tools/cluster/run-local.sh MAP OUT TILES [JOBS] [-- OPTIONS...]
#
#   MAP     the photon map to detect (read by every tile; never written)
#   OUT     the detected map; the same file `photonkit detect MAP -o OUT OPTIONS` writes
#           (byte for byte when SOURCE_DATE_EPOCH is set, as for any reproducible run)
#   TILES   how many tiles (2 → 2×1, 4 → 2×2, 9 → 3×3; docs/tiles.md)
#   JOBS    tiles run at once (default: the number of processors)
#   OPTIONS passed to every tile command (e.g. --kc 30 --method world-pca)
#
# STAGE names the stage, `detect` (default), `relax` (OUT is then `photonkit relax MAP`'s) or
# `render` (OUT is then the image `photonkit render MAP -o OUT OPTIONS` writes, made by
# `photonkit render MAP --parts …` from the parts).
# PHOTONKIT names the binary (default: photonkit on PATH). The parts go to a temporary
# directory beside OUT, removed at the end (also on failure or interrupt).
set -euo pipefail

usage() { sed -n '5,15p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 64; }
[ $# -ge 3 ] || usage
map=$1 out=$2 tiles=$3
shift 3
jobs=$(getconf _NPROCESSORS_ONLN 2>/dev/null || echo 2)
if [ $# -gt 0 ] && [ "$1" != "--" ]; then jobs=$1; shift; fi
if [ $# -gt 0 ] && [ "$1" = "--" ]; then shift; fi
case $tiles in ''|*[!0-9]*|0) echo "run-local.sh: TILES must be a whole number ≥ 1, not '$tiles'" >&2; exit 64;; esac
case $jobs in ''|*[!0-9]*|0) echo "run-local.sh: JOBS must be a whole number ≥ 1, not '$jobs'" >&2; exit 64;; esac
photonkit=${PHOTONKIT:-photonkit}
stage=${STAGE:-detect}
case $stage in detect|relax|render) ;; *) echo "run-local.sh: STAGE must be detect, relax or render, not '$stage'" >&2; exit 64;; esac

parts=$(mktemp -d "$(dirname -- "$out")/.tiles-XXXXXX")
trap 'rm -rf -- "$parts"' EXIT INT TERM HUP

# One command per tile, exactly as the cluster recipes run them.
seq 0 $((tiles - 1)) | xargs -P "$jobs" -I{} \
    "$photonkit" --quiet "$stage" "$map" --tile "{}/$tiles" -o "$parts/part-{}.phm" "$@"
if [ "$stage" = render ]; then
    "$photonkit" --quiet render "$map" --parts "$parts"/part-*.phm -o "$out" "$@"
else
    "$photonkit" --quiet merge --map "$map" "$parts"/part-*.phm -o "$out"
fi
