"""Loading the structures: what `render` costs before its first sample (issue 10).

    .venv/bin/python -m benchmarks.bench_load [--only shell,gerris] [--runs 3] [--write-docs]

For each dataset (bench_render's stage outputs, built on first use) this measures
the bytes of its three structure files (bricks, regions, bvh) and reading them
(`cat` to /dev/null). It then runs `exabricks render` of a 64² frame as a whole
command: the frame is so small that the command is its loading (map and check
the files, the OpenCL context and the cached program, upload, one frame's
visibility, write). The same command on a 64-cell dataset is the baseline: the
interpreter, the modules and the OpenCL runtime. Warm figures are medians of
--runs. Cold ones (read and command after the page cache is dropped) are taken
only where this process may write /proc/sys/vm/drop_caches (root). Then, in one
process, the parts: `load_structures` (mapped loads, every check and CRC), the
`DeviceDataset` (layout conversions and upload) and one frame's visibility
(`DeviceDataset.visibility` with the default transfer function).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.bench_budget import tiny_scene
from benchmarks.bench_render import ensure_scene

SECTION = "Loading the structures"
DEFAULT = ("shell", "gerris", "amrex")
FILES = ("bricks", "regions", "bvh")
NOTES = """
What a `render` command costs besides its frames, against what reading its files
costs. *read*: `cat` of the three files to /dev/null. *command*: `exabricks render`
of a 64² frame (so small that the command is its loading), as a whole process;
*above baseline*: less the same command on a 64-cell dataset (interpreter,
modules, OpenCL runtime and context, cached program). *peak*: the command's peak
resident memory (the mapped files' pages it touches count, as they do for the
kernel reading them in place); */ files*: the peak above the baseline's over the
files' bytes. The parts are measured in one warm process: `load_structures`
(the three mapped loads with every check and CRC, in steps), the `DeviceDataset`
(brick boxes, dims and BVH links written in the device's layout, the buffers
made), and one frame's node and region visibility for the default transfer
function. Cold: after `echo 3 > /proc/sys/vm/drop_caches` (only as root).

*fresh memory*: new processes each allocate and first write 256 MiB, then write
them again. On a virtual machine whose guest hands free pages back to the host
(Firecracker with `page_reporting`, as the one of 2026-12-03), a first write of
pages the process never used costs from about as much as the second to a hundred
times more, differently in every run. Every fresh array of a command pays it:
there the DeviceDataset's brick boxes and dims in the device's layout (74 MB on the
thin shells) took from 0.06 to 0.9 s in four runs of the same process. That, not
the checks, is most of the spread between runs.

Before the loading work of ab99888 (this script run on 4e7817c minutes before it,
on the same AMD EPYC, 2026-12-03): baseline command 1.88 s, peak 238 MiB; thin
shells 5.67 / 4.24 s (2.35 s above the baseline), peak 658 MiB (1.20 of the files
above the baseline), parts 0.91 / 0.69 / 0.25 s. What changed then: the alignment
check in NumPy steps instead of numba (every command that builds nothing no longer
starts numba: 0.8 s and 100 MiB of the baseline), the region and BVH boxes read by
the kernels as the files hold them (no float4 copies), the brick rows written in
place, and the visibility's opacity test by a prefix count of the positive knots
instead of a sparse-table maximum.

After `brick` began joining the small bricks of the k-d partition (648684f), the
thin shells' three files hold 256 MiB instead of 350 (1.06 M bricks instead of 2.33
M): 1.17 s above the baseline instead of 1.46 s (0.87 s to read the files cold),
peak 390 MiB instead of 504 (1.00 of the files above the baseline; the aim is
about 1.2), parts 0.48 / 0.16 / 0.11 s instead of 0.67 / 0.22 / 0.12 s (this table
against the one of 2026-12-03 22:54 on the same AMD EPYC). What the 0.75 s of
parts are, per step, is in docs/design.md ("Intermediate files"): every index the kernels
follow is checked, vectorised, and the CRC of every array is computed once.
"""


def drop_caches() -> bool:
    """Drop the page cache; False where this process may not."""
    try:
        subprocess.run(["sync"], check=True)
        Path("/proc/sys/vm/drop_caches").write_text("3\n")
        return True
    except OSError:
        return False


def read_seconds(files) -> float:
    start = time.perf_counter()
    subprocess.run(["cat", *map(str, files)], stdout=subprocess.DEVNULL, check=True)
    return time.perf_counter() - start


def command(files, field: str, out: Path) -> tuple[float, int]:
    """Wall seconds and peak RSS bytes of a 64² `exabricks render`."""
    wall, _, peak = benchdoc.run_child([*benchdoc.exabricks_command(), "render", *files,
                                        "--field", field, "--size", "64", "64",
                                        "--max-opacity", "1", "-o", out])
    return wall, peak


# The first touch of fresh memory in a new process, against writing it again: on some
# virtual machines (free page reporting) the first costs far more, and varies widely.
TOUCH = """
import time, numpy as np
t = time.perf_counter(); a = np.ones(64 << 20, np.float32); t1 = time.perf_counter()
a[:] = 2; print(t1 - t, time.perf_counter() - t1)
"""


def first_touch(runs: int) -> tuple[list[float], float]:
    """Seconds to allocate and first write 256 MiB in each of `runs` fresh processes, and
    the median seconds to write them again."""
    out = [subprocess.run([sys.executable, "-c", TOUCH], capture_output=True, text=True,
                          check=True).stdout.split() for _ in range(runs)]
    return sorted(float(a) for a, _ in out), statistics.median(float(b) for _, b in out)


def parts(files, field: str) -> tuple[float, float, float]:
    """Seconds of load_structures, DeviceDataset and one frame's visibility."""
    from exabricks.engine.device_data import DeviceDataset, load_structures
    from exabricks.picture.transfer_function import default_transfer_function

    start = time.perf_counter()
    b, r, v = load_structures(*files)
    loaded = time.perf_counter()
    scene = DeviceDataset(b, r, v, field=field)
    made = time.perf_counter()
    values = b.values[b.field_index(field)]
    tf = default_transfer_function((float(np.nanmin(values)), float(np.nanmax(values))))
    start_v = time.perf_counter()
    scene.visibility(layers=[(field, tf)])
    end = time.perf_counter()
    return loaded - start, made - loaded, end - start_v


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    benchdoc.add_common_args(parser, runs=3)
    parser.add_argument("--work", type=Path, default=benchdoc.BENCH / "render",
                        help="where the stage outputs are kept")
    args = parser.parse_args(argv)
    known = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, [k for k in DEFAULT if k in known])
    can_drop = drop_caches()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        out = tmp / "frame.exr"
        base_files = tiny_scene(tmp, "rho")
        command(base_files, "rho", out)  # warm-up
        base = [command(base_files, "rho", out) for _ in range(args.runs)]
        base_wall = statistics.median(w for w, _ in base)
        base_peak = max(p for _, p in base)
        for key in keys:
            dataset = known[key]
            d = ensure_scene(args.work, dataset)
            files = [d / f"{n}.npz" for n in FILES]
            size = sum(f.stat().st_size for f in files)
            cold_read = cold_wall = None
            if can_drop and drop_caches():
                cold_read = read_seconds(files)
                drop_caches()
                cold_wall = command(files, dataset.field, out)[0]
            read = statistics.median(read_seconds(files) for _ in range(args.runs))
            warm = [command(files, dataset.field, out) for _ in range(args.runs)]
            wall = statistics.median(w for w, _ in warm)
            peak = max(p for _, p in warm)
            load, device, visible = (statistics.median(x) for x in
                                     zip(*(parts(files, dataset.field) for _ in range(args.runs))))
            cold = (f"{cold_read:.2f} / " if cold_read is not None else "")
            cold_cmd = (f"{cold_wall:.2f} / " if cold_wall is not None else "")
            rows.append(
                f"| {dataset.name} | {benchdoc.fmt_bytes(size)} | {cold}{read:.2f} | "
                f"{cold_cmd}{wall:.2f} | {wall - base_wall:.2f} | {benchdoc.fmt_bytes(peak)} | "
                f"{(peak - base_peak) / size:.2f} | {load:.2f} / {device:.2f} / {visible:.2f} |")
            print(rows[-1], flush=True)
    touch, again = first_touch(max(args.runs, 5))
    temperature = "cold / warm" if can_drop else "warm"
    body = "\n".join([
        f"`.venv/bin/python -m benchmarks.bench_load --runs {args.runs}"
        + (f" --only {','.join(keys)}" if args.only else "") + " --write-docs`",
        "",
        f"- machine: {benchdoc.machine(opencl=True)}",
        f"- baseline (64-cell dataset): command {base_wall:.2f} s, peak "
        f"{benchdoc.fmt_bytes(base_peak)}; medians of {args.runs} warm runs",
        f"- fresh memory: allocating and first writing 256 MiB took "
        f"{', '.join(f'{t:.2f}' for t in touch)} s in {len(touch)} new processes; writing "
        f"it again {again:.2f} s",
        "",
        f"| dataset | files | read s ({temperature}) | command s ({temperature}) | "
        "above baseline s (warm) | peak | peak above baseline / files | "
        "parts s: load + checks / device scene / visibility |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
        *rows,
        NOTES,
    ])
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
