#!/usr/bin/env bash
# build_pieces.sh - brick, regions and bvh of one large dataset on SLURM, each
# stage as a job array of N pieces followed by a join, chained with
# --dependency=afterok (6 jobs):
#
#   workflows/slurm/build_pieces.sh CELLS OUTDIR N
#
#   1. build_piece.sbatch brick, N array tasks: OUTDIR/pieces/bricks.I.npz
#   2. exabricks join -> OUTDIR/bricks.npz
#   3, 4. the same for regions -> OUTDIR/regions.npz
#   5, 6. the same for bvh -> OUTDIR/bvh.npz
#
# The three files equal those of `brick`, `regions` and `bvh` run in one
# process, array for array (docs/design-structures.md, "Builders by pieces"). Environment:
# BRICK_OPTIONS, REGIONS_OPTIONS, BVH_OPTIONS (more options of each stage, e.g.
# "--max-brick-width 16"), EXABRICKS (the exabricks command, default `exabricks`
# on PATH), SBATCH_OPTIONS (e.g. "--partition=long --mem=64G"), WAIT=1 to return
# only when the last join has ended, with status 0 only if it completed and
# OUTDIR/bvh.npz exists. Prints the job ids.
set -euo pipefail
if (( $# != 3 )) || ! [[ $3 =~ ^[1-9][0-9]*$ ]]; then
    echo "usage: $0 CELLS OUTDIR N   (N pieces per stage, N >= 1)" >&2
    exit 2
fi
here=$(cd "$(dirname "$0")" && pwd)
cells=$(cd "$(dirname "$1")" && pwd)/$(basename "$1")
mkdir -p "$2/pieces"
outdir=$(cd "$2" && pwd)
n=$3
eb=${EXABRICKS:-exabricks}
# shellcheck disable=SC2086  # SBATCH_OPTIONS is a list of options
submit() { sbatch --parsable --kill-on-invalid-dep=yes ${SBATCH_OPTIONS:-} "$@"; }
after=()
input=$cells
jobs=""
wait_flag=()
for stage in brick:bricks:BRICK_OPTIONS regions:regions:REGIONS_OPTIONS bvh:bvh:BVH_OPTIONS; do
    IFS=: read -r command name options <<< "$stage"
    prefix=$outdir/pieces/$name
    # shellcheck disable=SC2086  # the stage's options are a list
    array=$(submit "${after[@]}" --array=0-$((n - 1)) -o "$outdir/pieces/$name-%a.log" \
            "$here/build_piece.sbatch" "$command" "$input" "$prefix" ${!options:-})
    list=$(for ((i = 0; i < n; i++)); do printf "'%s.%d.npz' " "$prefix" "$i"; done)
    [[ $name == bvh && ${WAIT:-0} == 1 ]] && wait_flag=(--wait)
    join=$(submit "${wait_flag[@]}" --dependency=afterok:"$array" -o "$outdir/pieces/$name-join.log" \
           --job-name=exabricks-join --wrap "$eb join $list -o '$outdir/$name.npz'")
    jobs+="$name=$array $name-join=$join "
    after=(--dependency=afterok:"$join")
    input=$outdir/$name.npz
done
echo "${jobs% }"
if [[ ${WAIT:-0} == 1 ]]; then  # sbatch --wait returns 0 for a cancelled job: ask
    state=$(scontrol -o show job "$join" | grep -o 'JobState=[A-Z_]*' || true)
    if [[ $state != JobState=COMPLETED || ! -s $outdir/bvh.npz ]]; then
        echo "build_pieces.sh: the last join $join ended ${state:-unknown} (see $outdir/pieces/*.log)" >&2
        exit 1
    fi
fi
