#!/usr/bin/env bash
# Run a stage tile by tile on a Slurm cluster: a job array with one task per tile, each running
# `photonkit STAGE MAP --tile i/n -o PART [OPTIONS]`, then a job that waits for them all
# (`--dependency=afterok`) and makes OUT from the parts: `photonkit merge` for detect and relax,
# `photonkit render MAP --parts PART... -o OUT [OPTIONS]` for render. The per-tile commands are
# the ones tools/cluster/run-local.sh runs (docs/tiles.md).
#
#   [STAGE=relax|render] [WAIT=1] tools/cluster/tiles-slurm.sh MAP OUT TILES [OPTIONS...]
#
# submits TILES array tasks (this script again, which then runs its tile) and the final job.
# WAIT=1 returns when the final job ends, with its status. TILE_CPUS (default 4) and TILE_MEMORY
# (default 8G) are each task's share of a node; PHOTONKIT names the binary. MAP, OUT and the parts
# (OUT.parts/) must be on a file system every node mounts.
#
# Run on a one-node Slurm 22.05 (Debian's slurm-wlm) for detect, relax and render: each OUT was
# byte for byte the one the stage writes without tiles (docs/tiles.md, "Tiles as jobs").
set -euo pipefail
photonkit=${PHOTONKIT:-photonkit}
stage=${STAGE:-detect}
case $stage in detect|relax|render) ;; *) echo "tiles-slurm.sh: STAGE must be detect, relax or render, not '$stage'" >&2; exit 64;; esac

if [ -n "${SLURM_ARRAY_TASK_ID:-}" ]; then
    # One array task: its tile. MAP, PARTS, TILES and the options come from the submission below.
    exec "$photonkit" --quiet "$stage" "$MAP" --tile "$SLURM_ARRAY_TASK_ID/$TILES" \
        -o "$PARTS/part-$SLURM_ARRAY_TASK_ID.phm" ${STAGE_OPTIONS:-}
fi

[ $# -ge 3 ] || { sed -n '8,13p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 64; }
map=$(realpath -- "$1") out=$(realpath -m -- "$2") tiles=$3
shift 3
case $tiles in ''|*[!0-9]*|0) echo "tiles-slurm.sh: TILES must be a whole number ≥ 1, not '$tiles'" >&2; exit 64;; esac
parts="$out.parts"
mkdir -p -- "$parts"
job=$(sbatch --parsable --array=0-$((tiles - 1)) --job-name="photonkit-$stage" \
    --cpus-per-task="${TILE_CPUS:-4}" --mem="${TILE_MEMORY:-8G}" --time=02:00:00 \
    --output="$parts/slurm-%A_%a.out" \
    --export=ALL,MAP="$map",PARTS="$parts",TILES="$tiles",STAGE="$stage",STAGE_OPTIONS="$*",PHOTONKIT="$photonkit" "$0")
if [ "$stage" = render ]; then
    final="'$photonkit' --quiet render '$map' --parts '$parts'/part-*.phm -o '$out' $*"
else
    final="'$photonkit' --quiet merge --map '$map' '$parts'/part-*.phm -o '$out'"
fi
wait_flag=()
[ "${WAIT:-0}" = 1 ] && wait_flag=(--wait)
echo "submitted $tiles tiles as job $job; the final job writes $out when all have succeeded" >&2
sbatch --parsable "${wait_flag[@]}" --dependency=afterok:"$job" --job-name="photonkit-$stage-parts" \
    --cpus-per-task="${TILE_CPUS:-4}" --mem="${TILE_MEMORY:-8G}" --output="$out.slurm-%j.out" \
    --wrap "$final && rm -r '$parts'"
