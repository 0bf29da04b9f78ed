"""Kernel builds ahead of the first picture (`exabricks devices --warm`).

The renderer builds one OpenCL program per variant of a frame (exabricks.device.kernel_abi
variant_defines: the number of fields, iso-surfaces, sample packets, ...) and, on
PoCL, compiles each kernel's work-group function at its first enqueue; the first
frame of a new variant on a machine waits for both (seconds to tens of seconds on a
small CPU; docs/benchmarks.md, "Kernel builds"), and the driver's caches keep them
for every later process. `warm` renders a tiny frame of each kind a new user draws
first, of the embedded Gerris plume, so that the renderer itself chooses the
variants: the same programs and work-group functions as the full-size frames.
"""

from __future__ import annotations

import time
from importlib import resources
from pathlib import Path

# The embedded dataset (the one `make demo` draws).
EMBEDDED = ("data", "gerris-plume", "plume7-1.cells")

# (what, eb.render options): the frames whose kernels are built ahead. Only the
# options that choose a program variant matter (fields, iso-surfaces, slices,
# reconstruction, level of detail); the frame is 8x8 pixels.
FRAMES = (
    # `exabricks render SOURCE -o x.png` and the README's quick start (one field, a volume)
    ("a volume (the default render)", {}),
    # the picture of `make demo` (the Makefile's $(OUT)/plume.png): a volume with an
    # iso-surface of the same field (tests/device/test_kernel_builds.py checks that, after `warm`,
    # that command builds nothing)
    ("a volume with an iso-surface (make demo)", {"field": "T", "iso": [0.45]}),
)
SIZE = (8, 8)


def embedded_dataset() -> Path:
    """The cells file of the embedded Gerris plume."""
    return Path(str(resources.files("exabricks").joinpath(*EMBEDDED)))


def warm(device=None, frames=FRAMES, on_frame=None) -> list[dict]:
    """Build the kernel programs (and work-group functions) of `frames` on `device`
    (an OpenCL device spec as `render --device`; default: EXABRICKS_DEVICE, else the
    default device) by rendering each at 8x8 pixels over the embedded dataset, read
    in memory (the structure cache is left alone). Returns, per frame, {"frame":
    what, "seconds": wall seconds, "programs": programs this process built for it,
    compiled or from the driver's cache}; `on_frame` is called with each as it is
    done."""
    from . import api
    from .device import opencl
    from .util import progress

    with progress.waiting("reading the embedded dataset (Gerris plume)…"):
        dataset = api.open(embedded_dataset(), cache=False)
    done = []
    for what, options in frames:
        start, built = time.perf_counter(), len(opencl.BUILDS)
        opencl.separate_compiles()
        api.render(dataset, device=device, size=SIZE, spp=1, **options)
        row = {"frame": what, "seconds": round(time.perf_counter() - start, 2),
               "programs": len(opencl.BUILDS) - built}
        done.append(row)
        if on_frame is not None:
            on_frame(row)
    return done
