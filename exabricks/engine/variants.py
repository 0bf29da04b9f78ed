"""Which render-kernel variants exist: the combinations of integrator, surfaces,
reconstruction, level of detail, brick lookup and region walk that a frame may
ask for (kernel_abi.variant_defines builds them), each one that does not
refused with one line before anything is built."""

from __future__ import annotations

from ..util.errors import ExabricksError

# Region walks (kernels/traversal.cl): "ordered" keeps a private min-heap of
# BVH nodes and regions per ray (one traversal per ray); "retrace" is the
# paper's §4 closest-hit traversal from the root for every region, stackless.
TRAVERSALS = ("ordered", "retrace")

# Where a sample finds the bricks it reconstructs from: the region's list (paper
# §3.2) or a per-sample descent of a tree over the brick supports (§6.4.2).
LOOKUPS = ("regions", "cell-location")


def check_choice(what: str, value: str, choices) -> None:
    """ExabricksError unless `value` is one of `choices`."""
    if value not in choices:
        raise ExabricksError(f"unknown {what} {value!r} (one of {', '.join(choices)})")


def check_variant(integrator: str, reconstruction: str, lod: bool, lookup: str, *, whole: bool,
                  occlusion: bool = False) -> None:
    """ExabricksError unless a frame of these choices can be drawn; `whole`: the
    renderer holds the whole dataset once (no domain of a partition, no instances);
    `occlusion`: ambient-occlusion rays asked for."""
    if integrator != "headlight" and not whole:
        raise ExabricksError(f"--integrator {integrator}: a shadow ray needs the whole dataset "
                             "in one piece; it does not work yet with --mirror (instances), "
                             "--memory-budget or MPI data mode (MPI image mode works)")
    if integrator == "path" and (lod or reconstruction == "vertex"):
        raise ExabricksError("--integrator path draws the basis or nearest reconstruction at full "
                             "resolution: --lod and the vertex reconstruction take --integrator shadow")
    if integrator == "path" and occlusion:
        raise ExabricksError("--integrator path: its environment light (--ambient) occludes by "
                             "itself; ambient-occlusion rays (--ao) are the other integrators'")
    if lookup == "cell-location" and (reconstruction != "basis" or lod):
        raise ExabricksError("the cell-location lookup exists for the basis reconstruction "
                             "without level of detail only")
    if lod and reconstruction != "basis":
        raise ExabricksError(f"level of detail (--lod) works with the basis reconstruction, "
                             f"not with {reconstruction}")
