"""Where an option acts: the conditions an `Option.applies` names, each declared
once with the words of its message. An option given (a flag, or a keyword of
eb.render) whose condition the scene does not meet would draw the same frame as
without it, so it is refused with one line naming it and what it needs; a
scene file's settings are not refused (a saved scene holds every setting)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..util.errors import ExabricksError


@dataclass(frozen=True)
class Condition:
    words: str  # what the option needs, as the message says it
    holds: Callable  # Scene -> bool


CONDITIONS = {
    # A directional light: the headlight draws from the camera alone.
    "light": Condition("--integrator shadow or path",
                       lambda s: s.lighting.integrator in ("shadow", "path")),
    "path": Condition("--integrator path", lambda s: s.lighting.integrator == "path"),
    "shadow": Condition("--integrator shadow", lambda s: s.lighting.integrator == "shadow"),
    "headlight": Condition("--integrator headlight",
                           lambda s: s.lighting.integrator == "headlight"),
    # The headlight's shading of the volume from its gradient.
    "shaded": Condition("--integrator headlight with --shading headlight",
                        lambda s: s.lighting.integrator == "headlight"
                        and s.lighting.shading == "headlight"),
    # A ray marched at a sampling rate, with jitter, gradients and early termination;
    # the path integrator tracks collisions instead.
    "marched": Condition("--integrator headlight or shadow",
                         lambda s: s.lighting.integrator != "path"),
    "surfaces": Condition("an iso-surface, a slice or a mesh (--iso, --slice, --mesh)",
                          lambda s: bool(s.isosurfaces or s.slices or s.meshes)),
}


def check_applies(scene, options, given: dict) -> None:
    """ExabricksError naming the first of `options` (Option) that `given` holds (by
    name; None: not given) and that does not act in `scene`."""
    for option in options:
        if given.get(option.name) is None:
            continue
        for name in option.applies:
            condition = CONDITIONS[name]
            if not condition.holds(scene):
                flag = option.flag
                if option.kind == "flag" and given[option.name] is False:
                    flag = "--no-" + flag[2:]
                raise ExabricksError(f"{flag} does not apply to this frame: it needs "
                                     f"{condition.words}")
