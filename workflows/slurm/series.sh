#!/usr/bin/env bash
# series.sh - a time series from simulation outputs to a movie on SLURM, as four
# jobs chained with --dependency=afterok (no step starts before the one it needs
# has succeeded; a failed array task cancels what depends on it):
#
#   FIELD=phi workflows/slurm/series.sh OUTDIR INPUT...     e.g. INPUT = run/plt*
#
#   1. preprocess_series.sbatch, one array task per INPUT: OUTDIR/step_%05d/; step 0
#      first, with its own structures, then the others on them: only their values
#      where their leaf cells are the same (a fixed hierarchy), else their own
#      structures (workflows/series_step.sh)
#   2. one task: the range of FIELD over every step -> OUTDIR/range.txt
#      (`exabricks info --field-range`), so that all frames share one colour map
#   3. render_series.sbatch, one array task per step: OUTDIR/frames/frame_%05d.png
#   4. one task: `exabricks movie` -> OUTDIR/movie.mp4
#
# Environment: FIELD (required: the field to render), RENDER_OPTIONS (more
# `exabricks render` options, e.g. "--size 1024 768 --colormap inferno"; the
# default camera frames the first step's bounds unless --camera is given),
# INGEST_OPTIONS, FPS (default 10), EXABRICKS (the exabricks command, default
# `exabricks` on PATH), SBATCH_OPTIONS (e.g. "--partition=long"), WAIT=1 to
# return only when the movie job has ended, with status 0 only if it completed.
# Prints the job ids (hierarchy: step 0's task; preprocess: the other steps').
set -euo pipefail
if (( $# < 2 )) || [[ -z ${FIELD:-} ]]; then
    echo "usage: FIELD=NAME $0 OUTDIR INPUT..." >&2
    exit 2
fi
here=$(cd "$(dirname "$0")" && pwd)
outdir=$1
shift
n=$#
eb=${EXABRICKS:-exabricks}
mkdir -p "$outdir"
outdir=$(cd "$outdir" && pwd)
# shellcheck disable=SC2086  # SBATCH_OPTIONS and RENDER_OPTIONS are lists of options
# (a dependency that can no longer be met cancels the job instead of leaving it pending)
submit() { sbatch --parsable --kill-on-invalid-dep=yes ${SBATCH_OPTIONS:-} "$@"; }
export SERIES_STEP="$here/../series_step.sh"
first=$(submit --array=0 -o "$outdir/preprocess-%a.log" "$here/preprocess_series.sbatch" "$outdir" "$@")
pre=$first steps=$first
if (( n > 1 )); then  # the other steps: their values on step 0's structures where the cells agree
    pre=$(HIERARCHY="$outdir/step_00000" submit --dependency=afterok:"$first" --array=1-$((n - 1)) \
          -o "$outdir/preprocess-%a.log" "$here/preprocess_series.sbatch" "$outdir" "$@")
    steps=$first:$pre
fi
# shellcheck disable=SC2016  # expanded by the job's shell: each step's values file or bricks
values='$(for s in step_*/step.txt; do read -r d v < "$s"; echo "${v:-$d/bricks.npz}"; done)'
range=$(submit --dependency=afterok:"$steps" -o "$outdir/range.log" \
        --job-name=exabricks-range \
        --wrap "cd '$outdir' && $eb info --field-range '$FIELD' $values > range.txt.tmp && mv range.txt.tmp range.txt")
# shellcheck disable=SC2086
render=$(RANGE_FILE="$outdir/range.txt" submit --dependency=afterok:"$range" \
         --array=0-$((n - 1)) -o "$outdir/render-%a.log" \
         "$here/render_series.sbatch" "$outdir" "$outdir/frames" --field "$FIELD" ${RENDER_OPTIONS:-})
wait_flag=()
[[ ${WAIT:-0} == 1 ]] && wait_flag=(--wait)
movie=$(submit "${wait_flag[@]}" --dependency=afterok:"$render" -o "$outdir/movie.log" \
        --job-name=exabricks-movie \
        --wrap "$eb movie '$outdir/frames/frame_*.png' -o '$outdir/movie.mp4' --fps ${FPS:-10}")
echo "hierarchy=$first preprocess=$pre range=$range render=$render movie=$movie"
if [[ ${WAIT:-0} == 1 ]]; then  # sbatch --wait returns 0 for a cancelled job: ask
    state=$(scontrol -o show job "$movie" | grep -o 'JobState=[A-Z_]*' || true)
    if [[ $state != JobState=COMPLETED || ! -s $outdir/movie.mp4 ]]; then
        echo "series.sh: the movie job $movie ended ${state:-unknown} (see $outdir/*.log)" >&2
        exit 1
    fi
fi
