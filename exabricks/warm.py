"""Kernel builds ahead of the first picture (`exabricks devices --warm [first|all]`).

The renderer builds one OpenCL program per variant of a frame (the feature table,
exabricks.engine.variants) and, on PoCL, compiles each kernel's work-group
function at its first enqueue; the first frame of a new variant on a machine waits
for both (seconds to tens of seconds on a small CPU; docs/benchmarks.md, "Kernel
builds"), and the driver's caches keep them for every later process. `warm`
renders a tiny frame of each variant asked for, of the embedded Gerris plume, so
that the renderer itself chooses the programs: the same programs and work-group
functions as the full-size frames.

* `first` (the default, and `make demo`'s): the frames a new user draws first,
  `FIRST`: the default render, make demo's iso-surface, the viewer's level of
  detail while moving, and the first shadow and path frames.
* `all`: every program a frame of one field can reach on the device
  (variants.declared), each drawn from a frame that chooses it.
"""

from __future__ import annotations

import time
from importlib import resources
from pathlib import Path

# The embedded dataset (the one `make demo` draws).
EMBEDDED = ("data", "gerris-plume", "plume7-1.cells")
FIELD, ISO_VALUE = "T", 0.45  # make demo's field and iso-value

# (what, the frame's axes of exabricks.engine.variants.AXES).
FIRST = (
    # `exabricks render SOURCE -o x.png` and the README's quick start (one field, a volume)
    ("a volume (the default render)", {}),
    # the picture of `make demo` (the Makefile's $(OUT)/plume.png): a volume with an
    # iso-surface (tests/device/test_kernel_builds.py checks that, after `warm`, that
    # command builds nothing)
    ("a volume with an iso-surface (make demo)", {"surfaces": True}),
    # the viewer's level of detail while the camera moves
    ("level of detail (the viewer while moving)", {"lod": True}),
    ("the shadow integrator", {"integrator": "shadow"}),
    ("the path integrator", {"integrator": "path"}),
)
SETS = ("first", "all")
SIZE = (8, 8)


def embedded_dataset() -> Path:
    """The cells file of the embedded Gerris plume."""
    return Path(str(resources.files("exabricks").joinpath(*EMBEDDED)))


def frames_of(which: str, kind: str) -> list[tuple[str, dict]]:
    """(what, axes) of the frames that warm set `which` (SETS) draws on a device of
    `kind` (variants.DEVICE_KINDS)."""
    from .engine import variants

    if which == "first":
        return list(FIRST)
    return [(v.label, vars(f)) for v, f in variants.declared_frames(kind).items()]


def warm(device=None, which: str = "first", on_frame=None) -> list[dict]:
    """Build the kernel programs (and work-group functions) of warm set `which`
    (SETS) on `device` (an OpenCL device spec as `render --device`; default:
    EXABRICKS_DEVICE, else the default device) by rendering each frame at 8x8
    pixels over the embedded dataset, read in memory (the structure cache is left
    alone). Returns, per frame, {"frame": what, "seconds": wall seconds,
    "programs": programs this process built for it, compiled or from the driver's
    cache}; `on_frame` is called with each as it is done."""
    from . import api
    from .device import opencl
    from .engine.variants import device_kind
    from .util import progress

    with progress.waiting("reading the embedded dataset (Gerris plume)…"):
        dataset = api.open(embedded_dataset(), cache=False)
    renderer = api.Renderer(dataset, device=device)
    frames = frames_of(which, device_kind(opencl.choose_device(device)))
    done = []
    with progress.bar(total=len(frames), desc="kernels", unit="program") as bar:
        for what, axes in frames:
            start, built = time.perf_counter(), len(opencl.BUILDS)
            opencl.separate_compiles()
            draw(renderer, axes)
            row = {"frame": what, "seconds": round(time.perf_counter() - start, 2),
                   "programs": len(opencl.BUILDS) - built}
            done.append(row)
            bar.update()
            if on_frame is not None:
                on_frame(row)
    return done


def draw(renderer, axes: dict) -> None:
    """An 8x8 frame of the embedded dataset whose program is that of `axes` (a
    point of variants.AXES, as a dict; its device kind and field count are the
    renderer's): its scene from render's options, its renderer turned
    to the axes' lookup, domain (the whole lattice, one domain) or overlapping
    copies (a mirror through the middle)."""
    import copy

    options = {"field": FIELD, "size": SIZE, "spp": 1,
               "integrator": axes.get("integrator", "headlight"),
               "reconstruction": axes.get("reconstruction", "basis")}
    if axes.get("surfaces"):
        options["iso"] = [ISO_VALUE]
    if axes.get("lod"):
        options["lod"] = 2.0
    if axes.get("gradient") == "central" and options["integrator"] == "headlight":
        options["gradient"] = "central"
    if axes.get("occlusion") and axes.get("surfaces"):
        options["ao_samples"] = 1
    if axes.get("mixture"):
        (lo, hi) = renderer.dataset.bounds
        options["mirror"] = [("x", (lo[0] + hi[0]) / 2)]
    scene = renderer.scene(**options)
    engine = renderer._on_device(scene.fields())
    if axes.get("lookup", "regions") != "regions":
        engine = engine.with_lookup(axes["lookup"])
    if axes.get("domain") and not axes.get("mixture"):
        engine = copy.copy(engine)
        engine.domain = ((-1e30, -1e30, -1e30, 0.0), (1e30, 1e30, 1e30, 0.0))
    engine.render_scene(scene, traversal=axes.get("traversal"))
