#!/usr/bin/env bash
# series_step.sh - one step of a time series, for the Make and SLURM pipelines
# (docs/time-series.md):
#
#   workflows/series_step.sh INPUT STEPDIR [HIERARCHY]
#
# With HIERARCHY (the directory of another step's bricks.npz, regions.npz and
# bvh.npz), the step is only its values on those structures:
#   exabricks values INPUT --bricks HIERARCHY/bricks.npz -o STEPDIR/values.npz
# and STEPDIR/step.txt says "HIERARCHY STEPDIR/values.npz". When INPUT's leaf cells
# differ from the hierarchy's (`exabricks values` says "the cells differ"), or
# without HIERARCHY, the step gets its own structures (ingest, brick, regions,
# bvh into STEPDIR) and step.txt says "STEPDIR". Any other error stops it.
#
# step.txt is written last, through a temporary file, so that its presence means
# the step is complete. What a render of the step takes:
#   read -r dir values < STEPDIR/step.txt
#   exabricks render "$dir"/{bricks,regions,bvh}.npz ${values:+--values "$values"} ...
# Environment: EXABRICKS (the exabricks command, default `exabricks` on PATH),
# INGEST_OPTIONS (more `ingest`/`values` options, e.g. "--field phi").
set -euo pipefail
if (( $# < 2 || $# > 3 )); then
    echo "usage: $0 INPUT STEPDIR [HIERARCHY]" >&2
    exit 2
fi
input=$1 step=$2 hierarchy=${3:-}
eb=${EXABRICKS:-exabricks}
mkdir -p "$step"
rm -f "$step/step.txt"
say=$step
if [[ -n $hierarchy ]]; then
    # shellcheck disable=SC2086  # INGEST_OPTIONS is a list of options
    if $eb values "$input" --bricks "$hierarchy/bricks.npz" -o "$step/values.npz" \
            ${INGEST_OPTIONS:-} 2> "$step/values.log"; then
        say="$hierarchy $step/values.npz"
    elif grep -q "the cells differ" "$step/values.log"; then
        echo "$input: its leaf cells differ from those of $hierarchy: building its own structures" >&2
        hierarchy=
    else
        cat "$step/values.log" >&2
        exit 1
    fi
fi
if [[ -z $hierarchy ]]; then
    # shellcheck disable=SC2086
    $eb ingest "$input" -o "$step/cells.npz" ${INGEST_OPTIONS:-}
    $eb brick "$step/cells.npz" -o "$step/bricks.npz"
    $eb regions "$step/bricks.npz" -o "$step/regions.npz"
    $eb bvh "$step/regions.npz" -o "$step/bvh.npz"
    rm -f "$step/values.npz"
fi
echo "$say" > "$step/step.txt.tmp"
mv "$step/step.txt.tmp" "$step/step.txt"
