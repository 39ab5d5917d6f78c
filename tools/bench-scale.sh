#!/bin/sh
# The scale benchmark of issue 25 (BENCHMARKS.md, "Scale"): the water scene through trace →
# detect → relax → collapse → relax → render with every stage that takes a memory budget
# given one, each stage timed and its peak resident set measured by /usr/bin/time.
#
#   tools/bench-scale.sh [EMITTED] [BUDGET] [DIR]      # defaults: 1e7 1G target/bench-scale
#
# Writes DIR/results.tsv (stage, wall seconds, peak RSS in KiB, output bytes, CPU seconds:
# user + system: the cost over both cores, where wall time also counts waits) and keeps only
# the map the next stage reads (the disk holds at most two maps at a time).
set -eu
EMITTED=${1:-1e7}
BUDGET=${2:-1G}
DIR=${3:-target/bench-scale}
PK=${PHOTONKIT:-target/release/photonkit}
SCENE=${SCENE:-samples/scenes/water.toml}
mkdir -p "$DIR"
OUT="$DIR/results.tsv"
printf 'stage\tseconds\tpeak_kib\toutput_bytes\tcpu_seconds\n' > "$OUT"
export SOURCE_DATE_EPOCH=1
stage() {
    name=$1; output=$2; shift 2
    /usr/bin/time -f '%e %M %U %S' -o "$DIR/time.txt" "$PK" --quiet "$@"
    read -r seconds peak user sys < "$DIR/time.txt"
    cpu=$(echo "$user $sys" | awk '{ printf "%.2f", $1 + $2 }')
    printf '%s\t%s\t%s\t%s\t%s\n' "$name" "$seconds" "$peak" "$(stat -c %s "$output")" "$cpu" | tee -a "$OUT"
}
stage trace "$DIR/traced.phm" trace "$SCENE" --photons "$EMITTED" --memory "$BUDGET" -o "$DIR/traced.phm"
stage detect "$DIR/detected.phm" detect "$DIR/traced.phm" --memory "$BUDGET" -o "$DIR/detected.phm"
rm "$DIR/traced.phm"
stage relax "$DIR/relaxed.phm" relax "$DIR/detected.phm" --memory "$BUDGET" -o "$DIR/relaxed.phm"
rm "$DIR/detected.phm"
stage collapse "$DIR/collapsed.phm" collapse "$DIR/relaxed.phm" -o "$DIR/collapsed.phm"
rm "$DIR/relaxed.phm"
stage relax-collapsed "$DIR/final.phm" relax "$DIR/collapsed.phm" --memory "$BUDGET" -o "$DIR/final.phm"
rm "$DIR/collapsed.phm"
stage render "$DIR/render.exr" render "$DIR/final.phm" --memory "$BUDGET" -o "$DIR/render.exr"
