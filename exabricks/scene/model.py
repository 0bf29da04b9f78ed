"""The scene model: camera, volume layers, iso-surfaces, slices, clipping,
lighting, background and render settings, and the limits of one frame.

`Scene` is what the renderer consumes (`exabricks.engine.renderer.render_scene`).
Every colour map and transfer function here is already stretched over its data
range; every position is in world units.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..picture.camera import Camera
from ..util.constants import MAX_COORDINATE, MAX_RADIANCE
from ..util.errors import ExabricksError
from ..util.vectors import unit
from ..picture.transfer_function import TransferFunction
from .modes import (AXES, MAX_CLIP_PLANES, MAX_INSTANCES, MAX_ISOSURFACES, MAX_MESHES, MAX_SLICES,
                    MAX_VOLUMES)
from .options import SCENE_OPTIONS

DEFAULT_COLORMAP = "viridis"
DEFAULT_FOVY = 30.0


@dataclass(frozen=True)
class VolumeLayer:
    """One field drawn as a participating medium with its own transfer function."""

    field: str
    transfer_function: TransferFunction


@dataclass(frozen=True)
class IsoSurface:
    """The surface where `field` equals `value` (basis field), drawn with `opacity`.

    Colour: the fixed RGB `color` (each in [0, 1]), or, when `color_field` is
    set, `colormap` (its RGB, over its range) evaluated on `color_field` at the hit.
    """

    field: str
    value: float
    color: tuple[float, float, float] = (0.9, 0.9, 0.9)
    opacity: float = 1.0
    color_field: str | None = None
    colormap: TransferFunction | None = None


@dataclass(frozen=True)
class Slice:
    """A plane through `point` with normal `normal` (world units), showing
    `colormap` (RGB over its range) of `field`, drawn with `opacity`."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    field: str
    colormap: TransferFunction
    opacity: float = 1.0


@dataclass(frozen=True)
class MeshLayer:
    """A triangle mesh file (OBJ, PLY, STL; world units; exabricks.mesh) drawn with
    `opacity`, in the fixed RGB `color`, or with `colormap` of `color_field` at
    the hit where that field has data."""

    path: str
    color: tuple[float, float, float] = (0.9, 0.9, 0.9)
    opacity: float = 1.0
    color_field: str | None = None
    colormap: TransferFunction | None = None


@dataclass(frozen=True)
class Instance:
    """A copy of the data and the meshes drawn besides them (docs/design-rendering.md,
    "Instances"): mirrored across the plane `mirror` = (axis, position), then
    rotated by `rotate` = (x, y, z, degrees) about that axis through the origin
    (right-handed), then moved by `translate`. World units."""

    mirror: tuple[str, float] | None = None
    rotate: tuple[float, float, float, float] | None = None
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def affine(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, t), float64: a point x of the data is drawn at R @ x + t (R orthogonal)."""
        m, t = np.eye(3), np.zeros(3)
        if self.mirror is not None:
            a = AXES.index(self.mirror[0])
            m[a, a], t[a] = -1.0, 2.0 * float(self.mirror[1])
        if self.rotate is not None:
            x, y, z = unit(self.rotate[:3])
            angle = np.radians(float(self.rotate[3]))
            k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
            r = np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)  # Rodrigues
            m, t = r @ m, r @ t
        return m, t + np.asarray(self.translate, np.float64)

    def check(self) -> None:
        if self.mirror is not None and (self.mirror[0] not in AXES
                                        or not abs(float(self.mirror[1])) <= MAX_COORDINATE):
            raise ExabricksError(f"a mirror is an axis (x, y or z) and a position within "
                                 f"{MAX_COORDINATE:g}, got {list(self.mirror)}")
        if self.rotate is not None:
            r = np.asarray(self.rotate, np.float64)
            if not (r.shape == (4,) and np.all(np.isfinite(r)) and np.any(r[:3] != 0)):
                raise ExabricksError(f"a rotation is a non-zero axis x, y, z and an angle in "
                                     f"degrees, all finite, got {list(self.rotate)}")
        if not (len(self.translate) == 3 and np.all(np.abs(self.translate) <= MAX_COORDINATE)):
            raise ExabricksError(f"a translation is three numbers within {MAX_COORDINATE:g}, "
                                 f"got {list(self.translate)}")


@dataclass(frozen=True)
class Clip:
    """What is kept: the inside of `box` ((lower xyz), (upper xyz)) and, for every
    plane (point, normal), the half-space (p - point) . normal >= 0. World units."""

    box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    planes: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = ()

    @property
    def active(self) -> bool:
        return self.box is not None or bool(self.planes)


@dataclass(frozen=True)
class Lighting:
    """shading: "headlight" (diffuse, plus Blinn-Phong `specular` with exponent
    `shininess` on surfaces) or "none"; gradient: the normals of volume samples
    (and of everything with "central"), "analytic" or "central"; ambient
    occlusion of surface hits: `ao_samples` rays (0: off) of length
    `ao_distance` world units (None: 10 finest cell widths); iso_gradient: the
    normals of iso-surfaces, "central" (the default: differences of the
    reconstructed field at the hit) or "analytic"; integrator: "headlight" (the
    above), "shadow" (a directional light, its transmittance through the scene,
    and an ambient term) or "path" (the same lights, path-traced through the
    volume layers with up to `bounces` scattering events and anisotropy g)."""

    shading: str = "headlight"
    gradient: str = "analytic"
    specular: float = 0.0
    shininess: float = 32.0
    ao_samples: int = 0
    ao_distance: float | None = None
    iso_gradient: str = "central"
    # the shadow integrator's light (docs/design-rendering.md, "Lights and shadows"):
    # the direction toward a directional light, world (None: the camera's key light,
    # above and to the left behind it), its colour and intensity, and the ambient term
    integrator: str = "headlight"
    # its transmittance toward the light: "cached" once per light (exabricks.engine.light_volume)
    # or "traced" by a shadow ray from every sample
    shadow_rays: str = "cached"
    light: tuple[float, float, float] | None = None
    light_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    light_intensity: float = 0.8
    ambient: float = 0.2
    # the path integrator's (docs/design-rendering.md, "Path tracing"): scattering
    # events of a path at most, and the Henyey-Greenstein phase function's g
    bounces: int = 8
    anisotropy: float = 0.0


@dataclass(frozen=True)
class Settings:
    """Render settings, by their flag names (docs/design.md)."""

    width: int = 512
    height: int = 512
    spp: int = 1
    sampling_rate: float = 2.0
    max_opacity: float = 0.98
    seed: int = 0
    jitter: bool = True
    unit_distance: float | None = None
    depth: bool = False
    reconstruction: str = "basis"
    lod: float = 0.0
    tf_lookup: str = "table"
    transparent: bool = False
    exposure: float = 0.0
    auto_exposure: bool = False
    denoise: bool = False


@dataclass(frozen=True)
class Scene:
    """The picture as one object (docs/scene.md), every default resolved: made by
    `Renderer.scene` (or `scene_from_options`), frozen (`replace` makes a changed
    copy). Positions and lengths in world units; colours and opacities in [0, 1].

    Parameters
    ----------
    camera
        The pinhole camera (exabricks.picture.camera.Camera).
    volumes
        Fields drawn as media, each with its transfer function (VolumeLayer).
    isosurfaces
        Iso-surfaces of the basis field (IsoSurface).
    slices
        Planes showing a field's colour map (Slice).
    meshes
        Triangle mesh files drawn with the data (MeshLayer).
    instances
        Copies of the data and the meshes (Instance), besides the identity.
    clip
        What is kept (default: everything).
    lighting
        Shading, gradients, ambient occlusion and the integrator (Lighting).
    background
        RGBA (default: transparent black).
    settings
        The render settings by their flag names (Settings).
    """

    camera: Camera
    volumes: tuple[VolumeLayer, ...] = ()
    isosurfaces: tuple[IsoSurface, ...] = ()
    slices: tuple[Slice, ...] = ()
    meshes: tuple[MeshLayer, ...] = ()
    instances: tuple[Instance, ...] = ()  # besides the identity, which is implied
    clip: Clip = Clip()
    lighting: Lighting = Lighting()
    background: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    settings: Settings = Settings()

    def fields(self) -> tuple[str, ...]:
        """Every field the frame reads, in first-use order (volumes, iso-surfaces
        and their colour fields, slices): the only ones uploaded.

        Returns
        -------
        tuple of str
            Each field once; the meshes' colour fields last.
        """
        names = [v.field for v in self.volumes]
        for s in self.isosurfaces:
            names += [s.field] + ([s.color_field] if s.color_field else [])
        names += [s.field for s in self.slices]
        names += [m.color_field for m in self.meshes if m.color_field]
        return tuple(dict.fromkeys(names))

    def replace(self, **changes) -> "Scene":
        """A copy of the scene with some parts changed (dataclasses.replace).

        Parameters
        ----------
        **changes
            Parts by their name (`camera=...`, `settings=...`), each a whole new value.

        Returns
        -------
        Scene
            Not checked until it is drawn (`check`); this scene stays as it is.

        Raises
        ------
        TypeError
            A name that is no part of a Scene.
        """
        return replace(self, **changes)

    def check(self) -> None:
        """ExabricksError for a scene no renderer can draw (limits, unknown modes).

        Raises
        ------
        ExabricksError
            More layers, iso-surfaces, slices, meshes, instances or clip planes than
            a frame holds; a setting outside its option's bounds; a value, point,
            normal, box, opacity or colour out of range; a colour field without a
            colour map; lights and exposure that could carry a pixel beyond float32.
        """
        lim = ((self.volumes, MAX_VOLUMES, "volume layers"),
               (self.isosurfaces, MAX_ISOSURFACES, "iso-surfaces"),
               (self.slices, MAX_SLICES, "slices"),
               (self.meshes, MAX_MESHES, "meshes"),
               (self.instances, MAX_INSTANCES, "instances besides the identity"),
               (self.clip.planes, MAX_CLIP_PLANES, "clip planes"))
        for items, most, what in lim:
            if len(items) > most:
                raise ExabricksError(f"{len(items)} {what}: at most {most} per frame")
        for option in SCENE_OPTIONS:  # each setting within the limits declared on its option
            if option.target is not None:
                option.coerce(option.value_in(self))
        for s in self.isosurfaces:
            if not np.isfinite(s.value):
                raise ExabricksError(f"iso-value {s.value} of field {s.field!r} is not finite")
            if not 0.0 <= s.opacity <= 1.0:
                raise ExabricksError(f"iso-surface opacity must lie in [0, 1], got {s.opacity}")
            if (s.color_field is None) != (s.colormap is None):
                raise ExabricksError("an iso-surface colour field needs a colour map and vice versa")
        for s in self.slices:
            n = np.asarray(s.normal, float)
            if not (np.all(np.isfinite(s.point)) and np.all(np.isfinite(n)) and np.any(n != 0)):
                raise ExabricksError(f"slice of {s.field!r} needs a finite point and a non-zero normal")
            if not 0.0 <= s.opacity <= 1.0:
                raise ExabricksError(f"slice opacity must lie in [0, 1], got {s.opacity}")
        for m in self.meshes:
            if not 0.0 <= m.opacity <= 1.0:
                raise ExabricksError(f"{m.path}: mesh opacity must lie in [0, 1], got {m.opacity}")
            if not all(0.0 <= c <= 1.0 for c in m.color) or len(m.color) != 3:
                raise ExabricksError(f"{m.path}: mesh colour must be three numbers in [0, 1]")
            if (m.color_field is None) != (m.colormap is None):
                raise ExabricksError("a mesh colour field needs a colour map and vice versa")
        for instance in self.instances:
            instance.check()
        for p, n in self.clip.planes:
            n = np.asarray(n, float)
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n)) and np.any(n != 0)):
                raise ExabricksError("a clip plane needs a finite point and a non-zero normal")
        if self.clip.box is not None:
            lo, hi = (np.asarray(b, float) for b in self.clip.box)
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
                raise ExabricksError(f"clip box {lo.tolist()} .. {hi.tolist()} must be finite "
                                     "with lower <= upper")
        bg = self.background
        if len(bg) != 4 or not all(0.0 <= c <= 1.0 for c in bg):
            raise ExabricksError(f"background must be RGBA in [0, 1], got {list(bg)}")
        self._check_radiance()

    def _check_radiance(self) -> None:
        """ExabricksError, before any sample is drawn, where the lights and the
        exposure could carry a pixel beyond float32 (a colour of at most 1 lit by
        the ambient term and the light, its highlight included, through the
        exposure's 2**stops; MAX_RADIANCE leaves room for the sums of samples)."""
        light = self.lighting
        if light.integrator == "headlight":
            peak, what = 1.0 + light.specular, f"--specular {light.specular:g}"
        else:
            peak = light.ambient + light.light_intensity * max(light.light_color) * (1 + light.specular)
            what = f"--light-intensity {light.light_intensity:g}, --ambient {light.ambient:g}"
            what += f", --specular {light.specular:g}" if light.specular else ""
        peak *= 2.0 ** self.settings.exposure
        if not peak <= MAX_RADIANCE:
            raise ExabricksError(f"{what} and --exposure {self.settings.exposure:g}: a pixel could "
                                 f"reach {peak:.3g}, beyond what the frame is computed in (at most "
                                 f"{MAX_RADIANCE:.3g}, float32 with room for its sums): lower them")
