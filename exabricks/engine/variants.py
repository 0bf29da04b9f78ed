"""The render kernel's features, declared once (docs/design-kernels.md, "The
feature table").

A frame is a point of `AXES`: what its scene asks for (integrator, surfaces,
reconstruction, level of detail, gradients) and what its renderer holds (the
device kind, the brick lookup, a domain of a partition, overlapping
instances). Each of `FEATURES` says how a frame chooses its value, which build
defines that value compiles in (a program per combination; none where the value
is PER_FRAME: the frame chooses it in eb_params), the eb_params member that
carries it per frame (`param`, `run_time_params`) and whether NVIDIA's register
cap spills with it. `REFUSALS` are the combinations no program draws, each refused
with one line before anything is built. From these alone come a frame's
program (`program_variant`), its build defines (`Variant.defines`), the
register cap (`Variant.capped`) and every program a frame can reach on a kind
of device (`declared`), which `exabricks devices --warm all` builds, and a
program per axis (`representatives`), which the kernel ABI test and the
offline gauge build.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, fields, make_dataclass
from types import SimpleNamespace
from typing import Callable

from ..device.kernel_abi import PACKET_WIDTH
from ..scene.modes import INTEGRATORS, RECONSTRUCTIONS
from ..util.errors import ExabricksError

# Region walks (kernels/traversal.cl): "ordered" keeps a private min-heap of
# BVH nodes and regions per ray (one traversal per ray); "retrace" is the
# paper's §4 closest-hit traversal from the root for every region, stackless.
TRAVERSALS = ("ordered", "retrace")

# Where a sample finds the bricks it reconstructs from: the region's list (paper
# §3.2) or a per-sample descent of a tree over the brick supports (§6.4.2).
LOOKUPS = ("regions", "cell-location")

# Kinds of device, each with its profile: sample packets and the ordered walk on
# CPUs, one sample at a time and the stackless re-trace walk on GPUs
# (docs/design-kernels.md, "Devices").
DEVICE_KINDS = ("cpu", "gpu")

# What a frame chooses, with every value it may take (the first: a new user's).
AXES = {
    "kind": DEVICE_KINDS,
    "n_fields": (1,),  # each count of uploaded fields is a program set of its own
    "integrator": INTEGRATORS,
    "surfaces": (False, True),  # iso-surfaces, slices or meshes
    "reconstruction": RECONSTRUCTIONS,
    "lod": (False, True),
    "gradient": ("analytic", "central"),
    "lookup": LOOKUPS,
    "domain": (False, True),  # a domain of a k-d partition (budget, MPI data mode)
    "mixture": (False, True),  # overlapping instances (--mirror)
    "occlusion": (False, True),  # ambient-occlusion rays (run time: refusals only)
    "traversal": (None, *TRAVERSALS),  # None: the device kind's walk
}


def device_kind(device) -> str:
    """The kind (DEVICE_KINDS) of an OpenCL device."""
    from ..device import opencl

    return "cpu" if opencl.is_cpu(device) else "gpu"


def uses_packets(f) -> bool:
    """Sample packets: the basis reconstruction from the regions' lists under the
    headlight and the shadow integrator, on CPUs (both give the same image)."""
    return (f.kind == "cpu" and f.lookup == "regions" and f.reconstruction == "basis"
            and f.integrator != "path")


@dataclass(frozen=True)
class Feature:
    """One axis of the render program."""

    name: str
    chosen: Callable  # frame (a point of AXES) -> the value, or PER_FRAME
    defines: Callable  # value (not PER_FRAME) -> the build defines that compile it in
    uncapped: Callable = lambda value: False  # whether NVIDIA's register cap spills with it
    why: str = ""  # why it is compiled in, or not (docs/design-kernels.md keeps the figures)
    # The eb_params member that carries the value per frame (a build whose define
    # fixes the value reads the define instead), and its value for a frame.
    param: str = ""
    value: Callable = int  # frame -> the member's value


# The value of a feature that no build compiles in: the frame chooses it in eb_params.
PER_FRAME = "per frame"


def _flag(define):
    return lambda on: (define,) if on else ()


FEATURES = (
    Feature("n_fields", lambda f: f.n_fields, lambda n: (f"EB_N_FIELDS={max(1, int(n))}",),
            why="private arrays of the fields' values and gradients"),
    Feature("reconstruction", lambda f: f.reconstruction if f.kind == "cpu" else PER_FRAME,
            lambda r: (f"EB_RECONSTRUCTION={RECONSTRUCTIONS.index(r)}",),
            param="reconstruction", value=lambda f: RECONSTRUCTIONS.index(f.reconstruction),
            why="compiled in on CPUs: chosen per frame, the vertex frame's one-sample path took "
            "1.32 times as long on PoCL; per frame on GPUs (no register more)"),
    Feature("cell_location", lambda f: f.lookup == "cell-location", _flag("EB_CELL_LOCATION")),
    Feature("surfaces", lambda f: f.surfaces, _flag("EB_SURFACES"), uncapped=bool,
            why="26 blocks of surface code in the sample loop"),
    Feature("lod", lambda f: f.lod if f.kind == "cpu" else PER_FRAME,
            lambda on: (f"EB_LOD={int(on)}",),
            why="compiled in on CPUs: chosen per frame, its branch per sample made the "
            "one-sample path 1.1-1.3 times slower on PoCL; per frame on GPUs "
            "(eb_params.lod_scale > 0; the GPU default keeps 96 registers, no spill)"),
    Feature("packets", uses_packets, lambda on: (f"EB_PACKET={PACKET_WIDTH}",) if on else (),
            uncapped=bool, why="the CPU profile: 8 samples reconstructed at once"),
    Feature("domain", lambda f: PER_FRAME, lambda on: (),
            why="a domain's frame takes its samples only (eb_params.domain): the test costs "
            "no measurable time and no register"),
    Feature("mixture", lambda f: f.mixture, _flag("EB_MIXTURE"), uncapped=bool),
    Feature("integrator", lambda f: f.integrator,
            lambda i: {"headlight": (), "shadow": ("EB_SHADOW",), "path": ("EB_PATH",)}[i],
            uncapped=lambda i: i == "shadow", why="a sample loop of its own"),
    Feature("ordered", lambda f: (f.traversal or ("ordered" if f.kind == "cpu" else "retrace"))
            == "ordered", _flag("EB_ORDERED"),
            why="the CPU profile: a heap walk whose private queue GPUs cannot afford"),
    # Volume samples' normals from central differences: the headlight's shading reads
    # them (the shadow and path integrators light volume samples without normals),
    # and nearest, piecewise constant, has no other (its iso-surfaces' normals are
    # central differences under every integrator: kernels/surfaces.cl).
    Feature("central", lambda f: f.integrator == "headlight"
            and (f.gradient == "central" or f.reconstruction == "nearest"), _flag("EB_CENTRAL"),
            uncapped=bool,
            why="six point queries per shaded sample: chosen per frame they spill the GPU "
            "default (436 B inline, 2.7 KB out of line)"),
)

Variant = make_dataclass("Variant", [(f.name, object) for f in FEATURES], frozen=True)
Variant.__doc__ = "One render program: a value of every feature (FEATURES), or PER_FRAME."


def _defines(self) -> tuple[str, ...]:
    """The build defines of this program."""
    values = ((f, getattr(self, f.name)) for f in FEATURES)
    return tuple(d for f, value in values if value != PER_FRAME for d in f.defines(value))


def _capped(self) -> bool:
    """Whether NVIDIA's register cap (kernel_abi.NV_REGISTER_CAP) applies: none
    of its features' values spills under it (the offline gauge)."""
    return not any(f.uncapped(getattr(self, f.name)) for f in FEATURES)


def _label(self) -> str:
    """The program in a few words: its defines less their prefix."""
    return " ".join(d.removeprefix("EB_") for d in self.defines)


Variant.defines = property(_defines)
Variant.capped = property(_capped)
Variant.label = property(_label)


@dataclass(frozen=True)
class Refusal:
    """A combination no program draws: `applies` (frame -> bool) and its one line."""

    applies: Callable
    message: str


REFUSALS = (
    Refusal(lambda f: f.integrator == "path" and (f.domain or f.mixture),
            "--integrator path: a scattered path needs the whole dataset in one piece; it does "
            "not work yet with --mirror (instances), --memory-budget or MPI data mode (MPI image "
            "mode works)"),
    Refusal(lambda f: f.integrator == "shadow" and f.mixture,
            "--integrator shadow: the light's transmittance does not cross instances that "
            "overlap yet (--mirror through the data)"),
    Refusal(lambda f: f.integrator == "path" and (f.lod or f.reconstruction == "vertex"),
            "--integrator path draws the basis or nearest reconstruction at full resolution: "
            "--lod and the vertex reconstruction take --integrator shadow"),
    Refusal(lambda f: f.integrator == "path" and f.occlusion,
            "--integrator path: its environment light (--ambient) occludes by itself; "
            "ambient-occlusion rays (--ao) are the other integrators'"),
    Refusal(lambda f: f.lookup == "cell-location" and (f.reconstruction != "basis" or f.lod),
            "the cell-location lookup exists for the basis reconstruction without level of "
            "detail only"),
    Refusal(lambda f: f.lod and f.reconstruction != "basis",
            "level of detail (--lod) works with the basis reconstruction, not with "
            "{reconstruction}"),
)


def frame(**given) -> SimpleNamespace:
    """A point of AXES: `given` values, a new user's for the others; ExabricksError
    for a value an axis does not take."""
    unknown = set(given) - set(AXES)
    if unknown:
        raise TypeError(f"unknown frame axes {', '.join(sorted(unknown))}")
    for name, value in given.items():
        if name != "n_fields" and value not in AXES[name]:
            what = {"lookup": "brick lookup"}.get(name, name)
            raise ExabricksError(f"unknown {what} {value!r} (one of "
                                 f"{', '.join(str(v) for v in AXES[name] if v is not None)})")
    return SimpleNamespace(**{**{k: v[0] for k, v in AXES.items()}, **given})


def refusal(f) -> str | None:
    """The line that refuses frame `f`, or None where a program draws it."""
    for r in REFUSALS:
        if r.applies(f):
            return r.message.format(**vars(f))
    return None


def program_variant(f) -> Variant:
    """The program that draws frame `f` (a point of AXES); ExabricksError where
    none does (REFUSALS)."""
    why = refusal(f)
    if why is not None:
        raise ExabricksError(why)
    return Variant(**{feature.name: feature.chosen(f) for feature in FEATURES})


def run_time_params(f) -> dict:
    """The eb_params members of frame `f`'s features (Feature.param)."""
    return {feature.param: feature.value(f) for feature in FEATURES if feature.param}


def variant(**values) -> Variant:
    """A Variant by feature values, a new user's for the others (tests, benchmarks)."""
    base = program_variant(frame())
    return Variant(**{**{f.name: getattr(base, f.name) for f in fields(Variant)}, **values})


# Axes only the Python API's benchmarks turn (Renderer(lookup=...), render(traversal=...)):
# their other values are not in a user's set.
BENCHMARK_AXES = ("lookup", "traversal")


def declared_frames(kind: str, n_fields: int = 1, *, benchmarks: bool = False) -> dict:
    """Every program a frame with `n_fields` fields can reach on a device of `kind`
    (DEVICE_KINDS), each with the first frame (a point of AXES) that chooses it, a
    new user's first, in a fixed order; with `benchmarks`, also those of the
    benchmarks' lookups and walks (BENCHMARK_AXES)."""
    axes = {**AXES, "kind": (kind,), "n_fields": (n_fields,)}
    if not benchmarks:
        axes.update({name: AXES[name][:1] for name in BENCHMARK_AXES})
    out = {}
    for values in itertools.product(*axes.values()):
        f = SimpleNamespace(**dict(zip(axes, values)))
        if refusal(f) is None:
            out.setdefault(program_variant(f), f)
    return out


def declared(kind: str, n_fields: int = 1, *, benchmarks: bool = False) -> tuple[Variant, ...]:
    """The programs of `declared_frames`."""
    return tuple(declared_frames(kind, n_fields, benchmarks=benchmarks))


def representatives(kind: str, n_fields: int = 1) -> tuple[Variant, ...]:
    """The programs of `representative_frames`."""
    return tuple(representative_frames(kind, n_fields))


def representative_frames(kind: str, n_fields: int = 1) -> dict:
    """A program per value of each axis on a device of `kind`, each with its frame:
    a new user's frame, that frame with one axis turned (BENCHMARK_AXES included),
    and each integrator with surfaces; what the kernel ABI test, the gauge and
    the kernel-build benchmark build where they cannot build all of `declared`."""
    turned = [{}] + [{axis: value} for axis, values in AXES.items()
                     if axis not in ("kind", "n_fields") for value in values[1:]]
    turned += [{"integrator": i, "surfaces": True} for i in INTEGRATORS[1:]]
    out = {}
    for given in turned:
        f = frame(kind=kind, n_fields=n_fields, **given)
        if refusal(f) is None:
            out.setdefault(program_variant(f), f)
    return out


def check_choice(what: str, value: str, choices) -> None:
    """ExabricksError unless `value` is one of `choices`."""
    if value not in choices:
        raise ExabricksError(f"unknown {what} {value!r} (one of {', '.join(choices)})")
