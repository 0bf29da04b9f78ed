"""exabricks.device.kernel_abi: the one declaration of the kernels' bounds, variant defines
and frame parameters, and the entry points' argument counts."""

from __future__ import annotations

import pyopencl as cl
import pytest
from helpers import DEVICES

from exabricks.device import kernel_abi, opencl
from exabricks.engine import variants
from exabricks.engine.variants import device_kind as kind_of


def argument_counts(device, programs) -> dict:
    context, _ = opencl.context_for(device)
    counts = {}
    for variant in programs:
        program = opencl.program_for(context, variant.defines, capped=variant.capped)
        for name in ("eb_render", "eb_probe"):
            kernel = opencl.kernel(program, name)
            counts[name, variant.label] = kernel.get_info(cl.kernel_info.NUM_ARGS)
    return counts


@pytest.mark.parametrize("device", DEVICES)
def test_no_entry_point_takes_more_than_24_arguments(device):
    """A domain's frame and the whole's take the same arguments (the domain is
    chosen at run time); these are the programs a CPU or GPU frame builds anyway."""
    dev = opencl.choose_device(device)
    default = variants.program_variant(variants.frame(kind=kind_of(dev)))
    domain = variants.program_variant(variants.frame(kind=kind_of(dev), domain=True))
    counts = argument_counts(dev, [default, domain])
    assert domain == default
    assert counts["eb_render", default.label] == 23  # the shadow programs' 24th: the light's cache
    assert max(counts.values()) <= 24


@pytest.mark.parametrize("device", DEVICES)
def test_a_program_of_every_axis_builds_within_24_arguments(device):
    """A program per value of each axis of the feature table on this device
    (variants.representatives: every define compiled at least once)."""
    dev = opencl.choose_device(device)
    counts = argument_counts(dev, variants.representatives(kind_of(dev)))
    assert max(counts.values()) <= 24, counts


@pytest.mark.slow
@pytest.mark.parametrize("device", DEVICES)
def test_every_declared_program_builds_within_24_arguments(device):
    """Every program a frame can reach on this device (variants.declared)."""
    dev = opencl.choose_device(device)
    counts = argument_counts(dev, variants.declared(kind_of(dev)))
    assert max(counts.values()) <= 24, counts


@pytest.mark.parametrize("device", DEVICES)
def test_params_struct_matches_the_device_layout(device):
    """The numpy dtype the host fills is the C struct the kernels read: every
    member's offset and the size, as this device's compiler lays eb_params out."""
    import numpy as np

    context, queue = opencl.context_for(opencl.choose_device(device))
    names = [name for name, _ in kernel_abi.PARAMS]
    body = "".join(f"    out[{i}] = (__global char *)&p->{n} - (__global char *)p;\n"
                   for i, n in enumerate(names))
    source = (kernel_abi.header() + "__kernel void layout(__global eb_params *p, "
              "__global long *out) {\n" + body + f"    out[{len(names)}] = sizeof(eb_params);\n}}\n")
    kernel = cl.Program(context, source).build().layout
    out = np.empty(len(names) + 1, np.int64)
    buf = opencl.empty_buffer(queue, out.nbytes)
    kernel(queue, (1,), None, opencl.to_device(queue, kernel_abi.params()), buf)
    opencl.read_back(queue, buf, out)
    dtype = kernel_abi.PARAMS_DTYPE
    assert out.tolist() == [dtype.fields[n][1] for n in names] + [dtype.itemsize]


@pytest.mark.parametrize("device", DEVICES[:1])
def test_kernels_refuse_to_build_without_the_header(device):
    context, _ = opencl.context_for(opencl.choose_device(device))
    source = (opencl.kernel_dir() / opencl.ENTRY_SOURCE).read_text()
    with pytest.raises(cl.RuntimeError, match="exabricks.device.kernel_abi"):
        cl.Program(context, source).build(options=opencl.build_options(variants.variant().defines))


def test_header_declares_every_bound_once():
    text = kernel_abi.header()
    for name, value in {**kernel_abi.LIMITS, **kernel_abi.TUNABLES}.items():
        assert text.count(f"#define {name} {value}\n") == 1
    assert "typedef struct {" in text and text.count(";") == len(kernel_abi.PARAMS) + 1
    # the kernels define none of them themselves
    for path in opencl.kernel_dir().glob("*.[ch]*"):
        source = path.read_text()
        for name in (*kernel_abi.LIMITS, *kernel_abi.TUNABLES, "EB_N_FIELDS"):
            assert f"#define {name} " not in source, (path.name, name)
