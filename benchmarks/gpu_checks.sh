#!/usr/bin/env bash
# The GPU checks of issue 36, item 3 (docs/benchmarks-gpu.md, "On a GPU"), prepared here
# and run in two calls of the device tool on a lent NVIDIA machine, whose Python
# (3.12, in the image) has numpy, numba, h5py, click and pillow but not pyopencl,
# and which reaches nothing outside itself.
#
#   benchmarks/gpu_checks.sh prepare        here: .gpu/ with the missing packages as
#                                           CPython 3.12 wheels and the shared data
#   benchmarks/gpu_checks.sh run 1          there (carry [".gpu"], timeout_s 600): the
#                                           device, the float64 reference tests, the
#                                           frames, what the kernels ask of the GPU,
#                                           and prefetched domains
#   benchmarks/gpu_checks.sh run 2          there, on the same warm machine: the
#                                           levers (no register cap, a lower one,
#                                           the heap walk instead of the stackless
#                                           one) against the tree as it is, and
#                                           the targets' frames (bench_peers, the
#                                           20.6 M-cell thin shells at 1024²)
#
# Every step has its own time limit (560 s at most for a part's steps together),
# and its output goes to $OUT/part<N>.txt (the device tool brings back at most 8
# files), so a step that fails or runs out of time leaves the others' figures.
# QUICK=1 shrinks every frame and round, to try the script on a CPU
# (EXABRICKS_DEVICE picks the device; OUT defaults to out/gpu-checks).
set -u
cd "$(dirname "$0")/.."
GPU=.gpu
OUT=${OUT:-out/gpu-checks}
QUICK=${QUICK:-0}
if [ "$QUICK" = 1 ]; then SIZE=128 BIG=256 RUNS=1 ROUNDS=1; else SIZE=1024 BIG=2048 RUNS=5 ROUNDS=5; fi

# The packages pyproject.toml needs that the machine's image lacks (KINDS.md's list).
WHEELS="pyopencl pytools platformdirs siphash24 OpenEXR jsonschema jsonschema-specifications
referencing rpds-py numexpr trimesh"

prepare() {
    grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo '/.gpu/' >> .git/info/exclude
    rm -rf "$GPU" && mkdir -p "$GPU/whl" "$GPU/data"
    # shellcheck disable=SC2086
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
        --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        --platform manylinux1_x86_64 -d "$GPU/whl" $WHEELS || exit 1
    data=$(.venv/bin/python -c "from benchmarks.benchdoc import data_dir; print(data_dir())") || exit 1
    cp -r "$data"/amrex-advection3d "$data"/athena-blast3d "$GPU/data/" || exit 1
    du -sh "$GPU"
}

# Run a step under its own time limit, its output appended to $LOG; the step's
# exit status is returned.
step() {
    local name=$1 limit=$2 status start=$SECONDS
    shift 2
    echo "== $name (at most ${limit} s): $*" | tee -a "$LOG"
    timeout "$limit" "$@" >> "$LOG" 2>&1
    status=$?
    echo "== $name: exit $status, $((SECONDS - start)) s" | tee -a "$LOG"
    return $status
}

setup_there() {
    mkdir -p "$OUT"
    if ! python3 -c "import pyopencl" 2>/dev/null; then
        python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
            --target /tmp/site "$GPU"/whl/*.whl || exit 1
        export PYTHONPATH=/tmp/site
    fi
    export PYTHONPATH=$PWD:${PYTHONPATH:-} EXABRICKS_TEST_DATA=$PWD/$GPU/data PYTHONUNBUFFERED=1
    # pyopencl's own ICD loader finds the vendor's driver through a folder of .icd files.
    if [ -z "${OCL_ICD_VENDORS:-}" ] && [ ! -e /etc/OpenCL/vendors/nvidia.icd ]; then
        lib=$(ldconfig -p | awk '/libnvidia-opencl.so.1/ {print $NF; exit}')
        [ -n "$lib" ] || lib=$(find / -name 'libnvidia-opencl.so.1' 2>/dev/null | head -n 1)
        if [ -n "$lib" ]; then
            mkdir -p /tmp/icd && echo "$lib" > /tmp/icd/nvidia.icd
            export OCL_ICD_VENDORS=/tmp/icd
        fi
    fi
    nvidia-smi -L 2>/dev/null || true
}

run1() {
    step devices 30 python3 -c "from exabricks.cli.main import main; main()" devices
    step tests 170 python3 -m pytest -q -x -n "$(nproc)" -m "not slow and not slurm" -k "not enzo" \
        -p no:cacheprovider tests/engine/test_render.py tests/engine/test_packets.py tests/engine/test_surfaces.py \
        tests/engine/test_probe.py tests/engine/test_reconstructions.py tests/engine/test_render_traversal.py \
        tests/engine/test_cell_location.py tests/picture/test_tf_table.py
    step render 120 python3 -m benchmarks.bench_render --only gerris,amrex,athena --runs "$RUNS" \
        --size "$SIZE"
    step resources 60 python3 -m benchmarks.kernel_resources
    step domain_cache 150 python3 -m benchmarks.bench_domain_cache --size 256 --budgets 8,16
}

run2() {
    local ab=(python3 -m benchmarks.ab_kernels --base-dir . --datasets amrex,gerris
              --variants volume --rate 10 --size "$BIG" --rounds "$ROUNDS")
    # kernel_abi.NV_REGISTER_CAP (96) raised to about what ptxas takes without a cap
    # (110 registers under 112, 112 left alone; 128 under 255), and lowered; the
    # ordered walk's heap
    step regcap112 90 "${ab[@]}" --options=-cl-nv-maxrregcount=112
    step regcap80 90 "${ab[@]}" --options=-cl-nv-maxrregcount=80
    step heapwalk 90 "${ab[@]}" --options=-DEB_ORDERED
    step peers 110 python3 -m benchmarks.bench_peers --no-yt --no-vtk \
        --datasets amrex,athena,gerris,shell256 --size "$SIZE" --runs "$RUNS" --images /tmp/peers-images \
        --docs /tmp/peers.md
    # The 20.6 M-cell thin shells (about 260 MiB of structures, built there).
    [ "$QUICK" = 1 ] || step shells 180 python3 -m benchmarks.bench_render --only shell \
        --runs "$RUNS" --size "$SIZE"
}

case "${1:-}" in
    prepare) prepare ;;
    run)
        setup_there
        LOG=$OUT/part${2:-}.txt
        : > "$LOG"
        case "${2:-}" in
            1) run1 ;;
            2) run2 ;;
            *) echo "usage: $0 run 1|2" >&2; exit 2 ;;
        esac ;;
    *) echo "usage: $0 prepare | run 1|2" >&2; exit 2 ;;
esac
