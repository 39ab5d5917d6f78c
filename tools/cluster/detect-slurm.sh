#!/usr/bin/env bash
# Detect (or relax) a photon map tile by tile on a Slurm cluster: a job array with one task per
# tile, each running `photonkit detect MAP --tile i/n -o PART`, then a merge job that waits for
# them (`--dependency=afterok`). The per-tile command is the one tools/cluster/run-local.sh
# runs; STAGE=relax runs `photonkit relax` tiles instead (both phases; docs/tiles.md).
#
# NOT RUN HERE: the machine this was written on has no Slurm. It is a recipe to adapt: the
# partition, the memory per task, and where MAP and the parts live (a file system every node
# mounts) are your cluster's.
#
# On the login node:
#   [STAGE=relax] tools/cluster/detect-slurm.sh MAP OUT TILES [STAGE-OPTIONS...]
# submits TILES array tasks (this script again, which then runs its tile) and the merge.
#SBATCH --job-name=photonkit-detect
#SBATCH --cpus-per-task=4
#SBATCH --mem=8G
#SBATCH --time=02:00:00
set -euo pipefail
photonkit=${PHOTONKIT:-photonkit}
stage=${STAGE:-detect}
case $stage in detect|relax) ;; *) echo "detect-slurm.sh: STAGE must be detect or relax, not '$stage'" >&2; exit 64;; esac

if [ -n "${SLURM_ARRAY_TASK_ID:-}" ]; then
    # One array task: its tile. MAP, PARTS and TILES come from the submission below.
    exec "$photonkit" --quiet "$stage" "$MAP" --tile "$SLURM_ARRAY_TASK_ID/$TILES" \
        -o "$PARTS/part-$SLURM_ARRAY_TASK_ID.phm" ${DETECT_OPTIONS:-}
fi

[ $# -ge 3 ] || { sed -n '11,13p' "$0" >&2; exit 64; }
map=$(realpath -- "$1") out=$(realpath -m -- "$2") tiles=$3
shift 3
parts="$out.parts"
mkdir -p -- "$parts"
job=$(sbatch --parsable --array=0-$((tiles - 1)) --job-name="photonkit-$stage" \
    --export=ALL,MAP="$map",PARTS="$parts",TILES="$tiles",STAGE="$stage",DETECT_OPTIONS="$*",PHOTONKIT="$photonkit" "$0")
sbatch --parsable --dependency=afterok:"$job" --job-name=photonkit-merge --mem=8G \
    --wrap "'$photonkit' --quiet merge --map '$map' '$parts'/part-*.phm -o '$out' && rm -r '$parts'"
echo "submitted tiles as job $job; the merge writes $out when all $tiles have succeeded" >&2
