"""What each kernel variant asks of an OpenCL device: per-work-item private memory,
local memory, the largest work-group and, on NVIDIA's driver, the registers, stack
frame and spills that its compiler reports.

    .venv/bin/python -m benchmarks.kernel_resources [--device SPEC]

Each variant is the render kernel (kernels/render.cl, eb_render) built with the
defines that exabricks.engine.renderer.Renderer passes for a mode (one field, the basis
reconstruction unless named), or the uniform-grid marcher (kernels/uniform_grid.cl).
Every variant is built afresh (into an empty pyopencl binary cache, so that the
driver writes its build log), with exabricks.device.opencl.BUILD_OPTIONS, plus -cl-nv-verbose on
NVIDIA's platform. Reported: CL_KERNEL_PRIVATE_MEM_SIZE (bytes per work-item that
do not fit registers: on a GPU, spills and private arrays in off-chip local memory),
CL_KERNEL_LOCAL_MEM_SIZE, CL_KERNEL_WORK_GROUP_SIZE, the preferred work-group
multiple, and the driver log's resource lines. Nothing is rendered.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from pathlib import Path

from exabricks.device import kernel_abi, opencl
from exabricks.engine import variants

ROOT = Path(__file__).resolve().parents[1]


# (label, source, kernel, exabricks.engine.variants.Variant or None): a program of each
# axis of the feature table on a GPU (variants.representatives) and the CPU default,
# labelled by their defines, and the uniform-grid marcher.
VARIANTS = tuple(
    [(v.label, "render.cl", "eb_render", v) for v in variants.representatives("gpu")]
    + [(v.label, "render.cl", "eb_render", v) for v in variants.declared("cpu")[:1]]
    + [("uniform-grid marcher", "uniform_grid.cl", "eb_uniform_render", None)])
ENTRY = re.compile(r"(?:entry function|Function properties for) '?(\w+)'?")


def report_of(log: str, name: str) -> list[str]:
    """The driver log's lines about kernel `name` (ptxas prints, per function, its
    registers, stack frame, spills and constant memory after naming it)."""
    lines, current = [], None
    for line in log.splitlines():
        m = ENTRY.search(line)
        if m:
            current = m.group(1)
            continue
        if current == name and line.strip():
            lines.append(re.sub(r"^ptxas\s+(info\s*:|\.)\s*", "", line.strip()))
    return lines


def build(context, device, source: str, variant, verbose: bool, cache_dir: str):
    """The program of a variant (None: the default's defines), built as
    exabricks.device.opencl.program_for builds it for `device` (None: for NVIDIA's
    driver, as ../shared/tools/gpu-proxy calls it)."""
    import pyopencl as cl

    nvidia = device is None or opencl.is_nvidia(device)
    variant = variant or variants.variant()
    options = opencl.build_options(variant.defines, nvidia, variant.capped)
    if verbose:
        options.append("-cl-nv-verbose")
    text = kernel_abi.header() + (opencl.kernel_dir() / source).read_text()
    program = cl.Program(context, text).build(
        options=options, cache_dir=cache_dir)
    log = program.get_build_info(device, cl.program_build_info.LOG) or ""
    return program, log


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="as `exabricks render --device`")
    args = parser.parse_args(argv)
    import pyopencl as cl

    device = opencl.choose_device(args.device)
    context = opencl.context_for(device)[0]
    nvidia = opencl.is_nvidia(device)
    print(f"device: {device.name.strip()} ({device.platform.version.strip()}), "
          f"{device.max_compute_units} compute units, "
          f"{device.local_mem_size // 1024} KiB local memory per work-group")
    info = cl.kernel_work_group_info
    print("| variant | private B/work-item | local B | max work-group | preferred multiple "
          "| driver's resource report |")
    print("|---|---:|---:|---:|---:|---|")
    for label, source, name, variant in VARIANTS:
        with tempfile.TemporaryDirectory() as cache_dir:
            program, log = build(context, device, source, variant, nvidia, cache_dir)
        kernel = cl.Kernel(program, name)
        lines = report_of(log, name)
        print(f"| {label} | {kernel.get_work_group_info(info.PRIVATE_MEM_SIZE, device)} "
              f"| {kernel.get_work_group_info(info.LOCAL_MEM_SIZE, device)} "
              f"| {kernel.get_work_group_info(info.WORK_GROUP_SIZE, device)} "
              f"| {kernel.get_work_group_info(info.PREFERRED_WORK_GROUP_SIZE_MULTIPLE, device)} "
              f"| {'; '.join(lines) or '-'} |", flush=True)
        warnings = [l.strip() for l in log.splitlines() if "warning" in l.lower()]
        for line in warnings[:10]:
            print(f"  {label}: {line}")
        if nvidia and not lines:
            print(log[-2000:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
