"""Where a frame's time goes: perf samples of the render kernel, by source function.

    .venv/bin/python -m benchmarks.profile_render [--only amrex,athena,...] [--size 1024]
                                                 [--frames 6] [--view render|peers]
                                                 [--rate 2] [--write-docs]

For each dataset (bench_render's inputs, bench-data/render/<name>/, made by
benchmarks/bench_render.py) and for each path (one sample at a time, the GPU's;
sample packets, the CPU default: kernels/packet.cl), a child process builds the
kernel with ``-g -DEB_PROFILE`` (line tables, and the region walk and the
sampling of a region kept out of line so that lines survive), renders a
warm-up frame and then --frames frames of the bench_render view (default
camera, transfer function and settings, headlight shading) under
``perf record`` (Debian package linux-perf; sampling the PoCL worker threads
with the rest of the process). Each sample in the kernel is attributed through
its source line (the innermost inlined one) to the kernel function around that
line, and the functions to the parts of a frame (PARTS); samples without a
line go by their symbol (SYMBOLS). Samples outside the
kernel (Python, the driver, page faults) are left out: the percentages are of
the kernel's time, and the "kernel share" column says how much of the process
that was.

--view peers profiles bench_peers' frame instead (its transfer function, opacity
unit and no shading, at --rate), the frame the targets against yt and VTK are
measured on. --write-docs replaces the "## Where a frame's time goes (perf)"
section of docs/benchmarks.md (with --view peers: "## Where bench_peers' frame
goes (perf)").
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

from benchmarks import benchdoc

ROOT = Path(__file__).resolve().parents[1]


SECTION = "Where a frame's time goes (perf)"
PEERS_SECTION = "Where bench_peers' frame goes (perf)"
PEERS_VIEW = ("As in \"Where a frame's time goes (perf)\", but each child renders "
              "bench_peers' frame of the dataset: its camera, the default transfer function "
              "with the opacity ramp scaled by bench_peers.ALPHA_SCALE (0.1), its opacity unit, "
              "early termination and seed, shading none, at --rate samples per finest cell.")
DEFAULT = ("amrex", "athena", "gerris", "enzo", "shell")
KERNELS = ROOT / "kernels"

# The parts of a frame, by kernel function (first match wins; a file name
# stands for every function of that file).
PARTS = (
    ("walk", ("traversal.cl",)),
    ("reconstruction", ("eb_add_grid", "eb_add_brick", "eb_add_reconstruction", "eb_reconstruct",
                        "eb_basis_zero", "eb_sample_region", "eb_sample_region_at",
                        "eb_packet_add_grid", "eb_packet_add_brick", "eb_packet_reconstruct",
                        "eb_packet_store", "eb_packet_lane", "eb_basis_value", "eb_fields")),
    ("transfer function", ("eb_transfer_function", "eb_lookup", "eb_packet_lookup")),
    ("opacity", ("eb_opacity_correct", "eb_log2_positive", "eb_exp2_nonpositive",
                 "eb_packet_log2_positive", "eb_packet_exp2_nonpositive")),
    ("shading", ("eb_headlight", "eb_field_gradient", "eb_basis_gradient")),
    ("medium (one step)", ("eb_medium_step", "eb_packet_medium")),
    ("compositing", ("eb_composite", "eb_packet_composite", "eb_vsum", "eb_sample_step",
                     "eb_batch_add", "eb_batch_take",
                     "eb_sample_interval", "eb_integrate_region", "eb_integrate")),
    ("sample placement", ("sampler.cl",)),
)
NOTES = """What it says. One sample at a time, the opacity correction (two fitted polynomials,
a chain of about 16 dependent multiply-adds) is the largest part wherever regions are
long (26-28 % on AMReX and Athena++ on an AMD EPYC with AVX2; 43-46 % on the Xeon with
AVX-512 of 2026-12-02): the scalar code cannot overlap one sample's chain with the next
one's. With sample packets the same polynomials run on eight samples at once (4-6 %;
8-16 % on that Xeon), and the reconstruction becomes the largest part (19-42 %: its
gathers, one per corner, lane and brick), followed by the transfer function's gathers
(8-19 %) and the walk (12-16 %), which packets do not touch. On octree-like data
(Gerris, the thin shells) one region visit holds 5-6 samples, so in a volume frame a
packet spans up to three visits (docs/design-kernels.md "Sample packets"). "sampling (no line)"
is code of the sampling functions that LLVM left without a source line; "ray set-up"
the samples in the kernel's entry function, which carry no source line (PoCL drops the
work-group function's debug info): the camera ray, the clip interval, the walk's start,
the per-region glue of the integrator and the pixel's write. It is largest where a
pixel takes few samples (Athena++ and Gerris, 17-19 %); PoCL's per-work-item context
arrays are not its cost (docs/design-kernels.md, "Work-group size and PoCL's context arrays").
"""
FUNCTION = re.compile(r"^(?:EB_INLINE|inline|__kernel|__attribute__\(\(noinline\)\))\b[^(]*?\b(\w+)\(")


def function_starts() -> dict[str, list[tuple[int, str]]]:
    """{file name: [(first line, function name)]} of every kernel source."""
    out = {}
    for path in sorted(KERNELS.glob("*.cl")) + sorted(KERNELS.glob("*.h")):
        starts = []
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            m = FUNCTION.match(line)
            if m:
                starts.append((n, m.group(1)))
        out[path.name] = starts
    return out


def part_of(file: str, function: str) -> str:
    for part, names in PARTS:
        if file in names or function in names:
            return part
    return "other kernel code"


# Kernel symbols of a profiling build (-DEB_PROFILE keeps these out of line), for
# samples whose address has no source line.
SYMBOLS = (("eb_walk_next", "walk"), ("eb_sample_interval", "sampling (no line)"),
           ("eb_batch_take", "sampling (no line)"), ("_pocl_kernel_eb_render", "ray set-up"))


def attribute(report: str, starts) -> tuple[Counter, float]:
    """(percent of the kernel's samples per part, the kernel's percent of all samples)
    from `perf report --sort sym,srcline` text."""
    parts: Counter = Counter()
    for line in report.splitlines():
        m = re.match(r"\s+([0-9.]+)%\s+\[\.\]\s+(\S+)\s+(\S+?):(\d+)\s*$", line)
        if not m:
            continue
        pct, symbol, file, n = float(m.group(1)), m.group(2), m.group(3), int(m.group(4))
        kernel_symbol = next((part for prefix, part in SYMBOLS if symbol.startswith(prefix)), None)
        if kernel_symbol is None:
            continue
        if file in starts and n > 0:
            function = "?"
            for first, name in starts[file]:
                if first <= n:
                    function = name
            parts[part_of(file, function)] += pct
        else:
            parts[kernel_symbol] += pct
    kernel = sum(parts.values())
    return Counter({k: 100.0 * v / kernel for k, v in parts.items()}) if kernel else parts, kernel


def child(name: str, packets: bool, size: int, frames: int, view: str, rate: float) -> None:
    """Render under the parent's perf record: a -g build, one warm-up frame, `frames` frames."""
    from exabricks.device import opencl
    from exabricks import schema
    from exabricks.picture.camera import default_camera
    from exabricks.engine.renderer import Renderer
    from exabricks.picture.transfer_function import default_transfer_function

    opencl.BUILD_OPTIONS = (*opencl.BUILD_OPTIONS, "-g", "-DEB_PROFILE")
    d = ROOT / "bench-data" / "render" / name
    b = schema.load(d / "bricks.npz", "bricks")
    renderer = Renderer(b, schema.load(d / "regions.npz", "regions"),
                        schema.load(d / "bvh.npz", "bvh"), packets=packets)
    values = b.values[renderer.dataset.field_indices[0]]
    value_range = (float(values.min()), float(values.max()))
    tf = default_transfer_function(value_range)
    lo, hi = schema.world_bounds(b)
    settings = {"camera": default_camera(lo, hi), "width": size, "height": size,
                "sampling_rate": rate}
    if view == "peers":  # bench_peers' frame: its opacity ramp, unit and no shading
        from benchmarks.peers import common as peers

        tf = peers.transfer_function(value_range)
        settings.update(shading="none", unit_distance=peers.opacity_unit((lo, hi)),
                        max_opacity=peers.MAX_OPACITY, seed=peers.SEED)
    renderer.render(transfer_function=tf, **settings)
    for _ in range(frames):
        renderer.render(transfer_function=tf, **settings)


def profile(name: str, packets: bool, size: int, frames: int, view: str, rate: float,
            starts) -> tuple[Counter, float]:
    command = lambda n: [sys.executable, __file__, "--child", name, str(int(packets)), str(size),
                         str(n), view, str(rate)]
    # The program build (minutes the first time) happens outside the profile.
    subprocess.run(command(0), check=True, cwd=ROOT, capture_output=True)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "perf.data"
        subprocess.run(["perf", "record", "-q", "-F", "499", "-o", str(data), *command(frames)],
                       check=True, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        report = subprocess.run(["perf", "report", "-i", str(data), "--no-children", "--stdio",
                                 "--sort", "sym,srcline"], check=True, capture_output=True,
                                text=True).stdout
    return attribute(report, starts)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        child(argv[1], argv[2] == "1", int(argv[3]), int(argv[4]), argv[5], float(argv[6]))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default=",".join(DEFAULT))
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--view", choices=("render", "peers"), default="render",
                        help="bench_render's frame (headlight shading), or bench_peers' "
                             "(its opacity ramp and unit, no shading)")
    parser.add_argument("--rate", type=float, default=2.0, help="samples per finest cell")
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    if shutil.which("perf") is None:
        print("error: perf not found (Debian package linux-perf)", file=sys.stderr)
        return 1
    starts = function_starts()
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    rows = {}
    for name in names:
        if not (ROOT / "bench-data" / "render" / name / "bvh.npz").is_file():
            print(f"error: bench-data/render/{name} missing: run benchmarks/bench_render.py "
                  f"--only {name} first", file=sys.stderr)
            return 1
        for packets in (False, True):
            parts, kernel = profile(name, packets, args.size, args.frames, args.view, args.rate,
                                    starts)
            rows[name, packets] = (parts, kernel)
            shown = ", ".join(f"{k} {v:.0f}%" for k, v in parts.most_common())
            print(f"{name} {'packets' if packets else 'one sample'}: kernel {kernel:.0f}% of the "
                  f"process; {shown}", flush=True)
    view = f" --view peers --rate {args.rate:g}" if args.view == "peers" else ""
    order = [p for p, _ in PARTS] + ["other kernel code", "sampling (no line)", "ray set-up"]
    head = "| dataset | path | kernel share | " + " | ".join(order) + " |"
    lines = [head, "|" + "---|" * (3 + len(order))]
    for (name, packets), (parts, kernel) in rows.items():
        lines.append(f"| {name} | {'packets' if packets else 'one sample'} | {kernel:.0f}% | "
                     + " | ".join(f"{parts.get(p, 0.0):.0f}%" for p in order) + " |")
    body = "\n".join([
        f"`.venv/bin/python -m benchmarks.profile_render --size {args.size} --frames {args.frames}"
        f" --only {','.join(names)}{view} --write-docs`",
        "",
        f"- machine: {benchdoc.machine(opencl=True)}",
        "",
        __doc__.split("\n\n")[2].replace("\n", " ") if args.view == "render" else PEERS_VIEW,
        "",
        *lines,
        "",
        NOTES if args.view == "render" else "",
    ])
    benchdoc.publish(SECTION if args.view == "render" else PEERS_SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
