"""The offline GPU gauge: NVIDIA registers, stack frame and spills of every kernel
variant, without a GPU, against the budgets the kernels must stay within.

    make kernel-resources          # the table into docs/benchmarks.md
    .venv/bin/python -m benchmarks.gpu_gauge [--check] [--write-docs] [--options ...]

It runs ../shared/tools/gpu-proxy (its README; `GPU_PROXY` names another copy),
which captures the program text and build options of benchmarks.kernel_resources'
own `build()` for every variant, compiles them with NVIDIA's libNVVM as the
driver's OpenCL compiler does and assembles them with `ptxas -arch=sm_90a -v`
(registers within 2 of the driver's on an H200). tests/device/test_gpu_gauge.py fails
when a kernel entry goes over its budget (BUDGETS), so that a change like
ae2d53f's (128 to 168 registers unseen for days) is caught the day it lands.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

from benchmarks.benchdoc import publish

ROOT = Path(__file__).resolve().parents[1]
GAUGE = Path(os.environ.get("GPU_PROXY", ROOT.parent / "shared" / "tools" / "gpu-proxy"))
SECTION = "Kernel resources on NVIDIA, offline (gpu-proxy)"

# (variant label of benchmarks.kernel_resources.VARIANTS: the program's defines less
# their EB_ prefix, exabricks.engine.variants.Variant.label; kernel entry) ->
# the most registers, stack frame bytes and spill bytes (stores + loads) it may take:
# today's figures, so that nothing grows unseen. The CPU's packet variant is built for
# PoCL; its NVIDIA figures (at ptxas' cap of 255, where the spills move by tens of
# bytes with any edit) are kept from growing. The 64 B stack of the capped variants is
# the frame of the driver's division slow path, which their entries call.
BUDGETS = {
    # the reconstruction and --lod chosen per frame in it since issue 61
    ("N_FIELDS=1", "eb_render"): (96, 64, 0),
    ("N_FIELDS=1", "eb_probe"): (60, 264, 0),
    # (the CPU default, measured for NVIDIA: 3216 B stack and 1048 B spills before the
    # per-pixel samples and depths shared one buffer, issue 62)
    ("N_FIELDS=1 RECONSTRUCTION=0 LOD=0 PACKET=8 ORDERED", "eb_render"): (255, 3280, 1012),
    ("N_FIELDS=1 SURFACES", "eb_render"): (186, 2656, 0),  # 248 before issue 61's run-time choices
    ("N_FIELDS=1 CENTRAL", "eb_render"): (128, 416, 0),
    ("N_FIELDS=1 CELL_LOCATION", "eb_render"): (96, 528, 0),
    # issue 61's feature table: a program of every axis (variants.representatives)
    ("N_FIELDS=1 MIXTURE", "eb_render"): (80, 1472, 0),
    ("N_FIELDS=1 ORDERED", "eb_render"): (96, 608, 0),
    ("uniform-grid marcher", "eb_uniform_render"): (56, 0, 0),
    # issue 52's shadow integrator: a shadow ray's walk inside the primary ray's,
    # uncapped (128 -> 152 registers with the reconstruction and --lod per frame, no
    # spill); with surfaces 255 registers and 16 B of spills before, 250 and none since
    # issue 62's cached transmittance read per sample beside the traced shadow rays
    # (chosen per frame): 152 -> 155 registers, with surfaces 250 -> 252 and 3104 ->
    # 3120 B; its columns' kernel (kernels/light_volume.cl) apart
    ("N_FIELDS=1 SHADOW", "eb_render"): (155, 560, 0),
    ("N_FIELDS=1 SURFACES SHADOW", "eb_render"): (252, 3120, 0),
    ("N_FIELDS=1 SHADOW", "eb_light_columns"): (96, 0, 0),
    ("N_FIELDS=1 SURFACES SHADOW", "eb_light_columns"): (126, 0, 0),
    # the path integrator: no region walk (delta and ratio tracking through the
    # majorant grid, a BVH point query per tentative collision: its descent's stack)
    ("N_FIELDS=1 PATH", "eb_render"): (96, 264, 0),
    # with surfaces: the nearest-surface walk (iso brackets, mesh BVH) and the
    # surfaces' transmittance beside tracking, uncapped as every surfaces variant
    # (231 -> 244 registers with the reconstruction per frame; no spill)
    ("N_FIELDS=1 SURFACES PATH", "eb_render"): (240, 2112, 0),
}
NOTES = """
Issue 51's targets: the GPU default at most 96 registers, no spills, a stack of at
most 512 B (met: 96 / 64 B / none); surfaces at most 128 registers without spills
(not met: 186 since issue 61, 254 before). How the GPU default came down from ae2d53f's 168 / 1648, each step
measured with the gauge on eb_render (registers / stack B):

| step (in order) | GPU default |
|---|---|
| 65d3f60 (before) | 168 / 1648 |
| 1. central-difference normals a build option | 128 / 1552 |
| 2. the stackless re-trace walk on GPUs, the heap in CPU builds only | 128 / 560 |
| 3. the gradient scales read where used | 128 / 64 |
| 4. eb_params by value | 112 / 64 |
| 5. NVIDIA's register cap of 96 | 96 / 64, no spills |

1. `EB_CENTRAL` (kernels/common.h), not a frame parameter: the six point queries
   of a central difference no longer hold registers in every frame.
2. kernels/traversal.cl, with the parents and child orders of
   exabricks.engine.walk_links; the heap walk under `EB_ORDERED`. The point query
   (probes, central differences, the path integrator) keeps its descent's stack
   of 256 B: stackless, it made central differences 1.3 times slower on PoCL,
   and the GPU default takes none.
3. Not a private array indexed by field, which put the whole eb_frame in memory.
4. kernels/common.h, `EB_PARAMS_ARG`: the offsets into the dataset's buffers are
   read from the parameter bank where used; from a `__constant` buffer 16 of them
   were loaded once and held, sign-extended, in 32 registers.
5. kernel_abi.NV_REGISTER_CAP, for the volume and path variants.

Where the registers of the capped variant go (`nvdisasm -plr` of the gauge's cubin): at
the peak, the eight cell loads of a brick's trilinear sum (reconstruction.cl,
eb_add_grid) with their 64-bit addresses, over about 80 values live through the
sample loop (the ray, the compositing state, the walk's and the sub-intervals'
state, the basis sums with their gradient, and the look's pointers). Under caps of
88 and 80 the variant spills 116 and 172 B. The surfaces variant inlines the iso
crossings, slices and meshes into the same loop (250 registers left alone; under a
cap of 128 it spills 2.9 KB), so its target needs those paths out of the sample loop.
Issue 52's surfaces under the path integrator split a surface hit into what it shows
(surfaces.cl, eb_surface_at, shared with the path integrator) and its shading: the
surfaces variant went from 250 registers and a 2544 B stack to 254 and 2656 B, the
shadow integrator's with surfaces from 3184 B and 156 B of spills to 3120 B and 8 B.
The surfaces variants keep eb_params in a `__constant` buffer: their out-of-line
functions (EB_COLD) take the frame's address, which would copy a by-value struct to
the stack (2848 B, spilling).
Issue 61 chose the reconstruction and level of detail per frame on GPUs
(eb_params.reconstruction, eb_params.lod_scale > 0): the GPU default stayed at 96
registers, 64 B and no spill once the samples per level went to the frame's counts
region by region (held per ray, they spilled 140 B); the surfaces variant went from
252 to 186 registers, the shadow integrator's with surfaces from 255 and 16 B of
spills to 250 and none. Central differences stay a build option: chosen per frame
they spilled the GPU default (436 B inline; 2,712 B out of line, the BVH, regions and
bricks passed by value).
"""
ROW = re.compile(r"^\| (?P<variant>[^|]+) \| (?P<function>\w+) \| (?P<registers>\d+) \| "
                 r"(?P<stack>\d+) \| (?P<stores>\d+) \| (?P<loads>\d+) \|")


def available() -> bool:
    """Whether the gauge and its compilers are installed (its setup.sh was run)."""
    home = Path(os.environ.get("GPU_PROXY_HOME", Path.home() / ".cache" / "gpu-proxy"))
    return (GAUGE / "ptx_proxy.sh").exists() and (home / "venv" / "bin" / "python").exists()


def measure(options: str = "", variants: str = "") -> tuple[dict, str]:
    """({(variant, function): (registers, stack, spills)}, the gauge's header line)
    of every kernel entry of this checkout."""
    args = [str(GAUGE / "ptx_proxy.sh"), "--checkout", str(ROOT)]
    args += [f"--options={options}"] if options else []
    args += ["--variants", variants] if variants else []
    proc = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
    if proc.returncode:
        raise RuntimeError(f"gpu-proxy failed ({proc.returncode}): {proc.stderr[-2000:]}")
    figures = {}
    for line in proc.stdout.splitlines():
        m = ROW.match(line)
        if m:
            spills = int(m["stores"]) + int(m["loads"])
            figures[(m["variant"].strip(), m["function"])] = (int(m["registers"]), int(m["stack"]), spills)
    return figures, proc.stdout.splitlines()[0] if proc.stdout else ""


def over_budget(figures: dict) -> list[str]:
    """What exceeds BUDGETS, one line each (an entry not measured counts)."""
    out = []
    for key, budget in BUDGETS.items():
        got = figures.get(key)
        if got is None:
            out.append(f"{key[0]} / {key[1]}: not measured")
        elif any(g > b for g, b in zip(got, budget)):
            out.append(f"{key[0]} / {key[1]}: {got[0]} registers, {got[1]} B stack, {got[2]} B spills "
                       f"(budget {budget[0]}, {budget[1]} B, {budget[2]} B)")
    return out


def table(figures: dict, header: str) -> str:
    rows = ["| variant | kernel | registers | stack frame B | spills B (stores + loads) | budget |",
            "|---|---|---:|---:|---:|---|"]
    for (variant, function), (regs, stack, spills) in figures.items():
        budget = BUDGETS.get((variant, function))
        rows.append(f"| {variant} | {function} | {regs} | {stack} | {spills} | "
                    + (f"{budget[0]} / {budget[1]} / {budget[2]}" if budget else "-") + " |")
    return (f"`make kernel-resources` ({header}).\n\n" + "\n".join(rows)
            + "\n\nThe budgets (registers / stack B / spills B) are what tests/device/test_gpu_gauge.py "
            "holds every entry to (benchmarks/gpu_gauge.py, BUDGETS).\n" + NOTES)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 when an entry is over budget")
    parser.add_argument("--write-docs", action="store_true")
    parser.add_argument("--options", default="", help="OpenCL build options to add")
    parser.add_argument("--variants", default="", help="comma-separated substrings of the labels")
    args = parser.parse_args(argv)
    if not available():
        print(f"gpu-proxy is not installed: run {GAUGE / 'setup.sh'} (as root) first", file=sys.stderr)
        return 1
    figures, header = measure(args.options, args.variants)
    publish(SECTION, table(figures, header), args.write_docs and not (args.options or args.variants))
    over = over_budget(figures) if args.check else []
    for line in over:
        print(f"over budget: {line}", file=sys.stderr)
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
