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

# (variant label of benchmarks.kernel_resources.VARIANTS, kernel entry) ->
# the most registers, stack frame bytes and spill bytes (stores + loads) it may take.
# The CPU's packet variant is built for PoCL; its NVIDIA figures are kept from growing.
# It sits at ptxas' cap of 255 registers, where the spills move by tens of bytes with
# any edit (two of its loads as literal constants instead: 1188 -> 1236 B), so its
# spill budget follows the commit that read the frame's scalars from eb_params
# (1152 -> 1188 B) while that commit took 80 B off every GPU variant's stack.
BUDGETS = {
    ("volume, one sample (GPU default)", "eb_render"): (168, 1648, 0),
    ("volume, one sample (GPU default)", "eb_probe"): (40, 264, 0),
    ("volume, sample packets (CPU default)", "eb_render"): (255, 3600, 1188),
    ("surfaces, slices, clipping, AO", "eb_render"): (252, 4272, 0),
    ("level of detail", "eb_render"): (168, 1904, 0),
    ("cell location", "eb_render"): (168, 1744, 0),
    ("vertex reconstruction", "eb_render"): (150, 1648, 0),
    ("uniform-grid marcher", "eb_uniform_render"): (54, 0, 0),
    # issue 52's shadow integrator: a shadow ray's walk (its own heap) inside the
    # primary ray's, so twice the walk's stack; with surfaces at the 255 cap, spilling
    ("shadow integrator", "eb_render"): (232, 2688, 0),
    ("shadow integrator, surfaces", "eb_render"): (255, 5680, 344),
    # the path integrator: no region walk (delta and ratio tracking through the
    # majorant grid, a BVH point query per tentative collision), so no heap
    ("path integrator", "eb_render"): (164, 264, 0),
}
NOTES = """
The budgets are today's figures, so that nothing grows unseen; issue 51's targets
(GPU default: at most 96 registers, no spills, a stack of at most 512 B; surfaces:
at most 128 registers) are not met yet. Where the 40 registers that ae2d53f added
come from, measured with the gauge on the GPU default variant (registers / stack B):

| change (experiments, not committed) | eb_render |
|---|---|
| ae2d53f's parent | 128 / 1648 |
| ae2d53f | 168 / 1648 |
| none (ed8e089) | 168 / 1728 |
| the nine BVH and region offsets (`P->node_lower_at` ...) as the constant 0 | 158 / 1728 |
| every `P->*_at` offset as the constant 0 | 160 / 1728 |
| eb_params passed by value instead of in a `__constant` buffer | 168 / 2176 |
| eb_frame's ten scalars read from `P` where used (committed since: issue 50) | 168 / 1648 |
| every scalar of `P` but counts and offsets as a literal constant | 166 / 2048 |
| `P` as `__constant volatile eb_params *`: every member reloaded where used (114 `ld.const`, not 40) | 168 / 1648 |
| `-cl-nv-maxrregcount=144` (at 3e55170) | 144 / 1712, 288 B spills |
| `-cl-nv-maxrregcount=128` (at 3e55170) | 128 / 1776, 828 B spills |

So the grouped buffers' offsets account for at most 10 of them, values of `P` held
from a hoisted load for none (reloading every member where it is used changes
nothing), and the frame's scalars for none (held on the stack as part of eb_frame: 80 B; the preprocessed
programs of ae2d53f and its parent have the same private arrays); passed by value,
the struct is copied to the stack because eb_frame keeps its address. What holds
the other 30 is still to be found in the `.ptx` (`ptx_proxy.sh --keep DIR`) of
ae2d53f against its parent. A guess to test next: the 84 pointer arguments were
reloaded from the parameter bank where needed, where each pointer now derived from
a grouped buffer (base + offset, 64 bits) is computed once and held in two
registers across the sample loop.
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
