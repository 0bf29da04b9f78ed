"""Every option of a render, declared once (docs/contributing.md, "Adding a render
option"): the command line's flags (exabricks.cli.options.declared makes the
click options of `render`, `probe` and the viewer from this table), the names
`scene_from_options` takes (`FLAGS`), and the Python API's keyword arguments.

An `Option` is data, not click: a name (the keyword and, with `-` for `_`, the
flag), what it takes (`kind`, `nargs`, `multiple`, limits) and its help text.
`SCENE_OPTIONS` describe the picture and override the scene file;
`JOB_OPTIONS` say how a render job runs (files, frames, memory, MPI).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..util.constants import FLOAT32_MAX, MAX_TITLE_CHARS
from ..util.errors import ExabricksError
from ..util.jsonfile import not_regular
from ..picture.scaling import SCALES
from .modes import (AXES, GRADIENTS, INTEGRATORS, MAX_AO_SAMPLES, MAX_BOUNCES, RECONSTRUCTIONS,
                    SHADING_MODES, SHADOW_RAYS, TF_LOOKUPS)


@dataclass(frozen=True)
class Option:
    """One render option.

    kind: "float", "int", "text", "file" (an existing file), "choice" (one of
    `choices`), "plane" (an axis x, y or z and a finite position, nargs 2),
    "numbers" (comma-separated numbers in [0, 1], as many as one of `counts`,
    or any number), "flag" (--name/--no-name), "size" (bytes: 2G, 512MiB).
    `low`/`high` bound a float or int (open bounds when `low_open`,
    `high_open`); floats must be finite and within float32's range (FLOAT32_MAX:
    the kernels read them as float32) unless `finite` is False (the camera
    vectors, which the camera itself checks and names).
    """

    name: str
    help: str
    kind: str = "float"
    nargs: int = 1
    multiple: bool = False
    metavar: str | None = None
    choices: tuple = ()
    counts: tuple | None = None
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    finite: bool = True
    envvar: str | None = None
    dest: str | None = None  # the keyword when it differs from `name`
    default: object = None
    # A scalar setting of the model: "part.attribute" of the Scene it sets (e.g.
    # "settings.spp"), and its key path in the scene file (default: (name,)). Such an
    # option needs nothing else: the scene file's schema node, the builder and
    # `scene_to_dict` all come from here.
    target: str | None = None
    scene_key: tuple | None = None
    description: str | None = None  # the schema's words for a valid value (default: made)
    # A target the kernels read: the eb_params member of this name
    # (exabricks.device.kernel_abi.PARAMS; a choice as its index in `choices`, a flag as 0/1),
    # filled from the scene for every frame; kernel code reads it as fr->P->NAME.
    kernel: bool = False
    # Where the option acts: names of exabricks.scene.applies.CONDITIONS that the
    # scene must meet; given where one fails, the option is refused.
    applies: tuple = ()

    @property
    def flag(self) -> str:
        return flag_name(self.name)

    @property
    def keyword(self) -> str:
        return self.dest or self.name

    def value_in(self, scene):
        """The value of this option's `target` in `scene` (exabricks.scene.Scene)."""
        part, _, attribute = self.target.partition(".")
        return getattr(getattr(scene, part), attribute)

    @property
    def key(self) -> tuple:
        """Where the option sits in a scene file."""
        return self.scene_key or (self.name,)

    def coerce(self, value):
        """A Python keyword's `value` as the command line would parse it (eb.render's
        options): numbers checked against the limits, `nargs` values as a tuple, a
        repeatable option as a tuple of them (one value alone is accepted);
        ExabricksError naming the keyword for anything else. None: not given."""
        if value is None:
            return None
        if self.multiple:
            items = [value] if self._single(value) else list(value)
            return tuple(self._one(v) for v in items) or None
        return self._one(value)

    def _single(self, value) -> bool:
        """Whether `value` is one value of a repeatable option (not a list of them)."""
        if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
            return True
        if self.kind == "plane":  # ("y", 0.0)
            return len(value) == 2 and isinstance(value[0], str)
        return self.nargs > 1 and len(value) == self.nargs and all(
            not hasattr(v, "__len__") for v in value)

    def _one(self, value):
        if self.kind == "plane":
            import math

            try:
                axis, position = value
                position = float(position)
            except (TypeError, ValueError):
                axis = position = None
            if axis not in AXES or position is None or not math.isfinite(position):
                raise ExabricksError(f"{self.keyword}: expected an axis (x, y or z) and a finite "
                                     f"position, got {value!r}")
            check_float32(position, self.keyword)
            return axis, position
        if self.nargs > 1:
            if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") \
                    or len(value) != self.nargs:
                raise ExabricksError(f"{self.keyword}: expected {self.nargs} values, got {value!r}")
            return tuple(self._scalar(v) for v in value)
        return self._scalar(value)

    def _scalar(self, value):
        import math
        import os

        bad = ExabricksError(f"{self.keyword}: expected {self._expected()}, got {value!r}")
        kind = self.kind
        if kind in ("float", "int"):
            # numpy's complex numbers have __float__, which drops the imaginary part
            complex_ = isinstance(value, complex) or getattr(getattr(value, "dtype", None),
                                                             "kind", "") == "c"
            if isinstance(value, bool) or complex_ or not hasattr(value, "__float__"):
                raise bad
            try:
                number = float(value)
            except (TypeError, ValueError, OverflowError):
                raise bad from None
            if kind == "int":
                if not math.isfinite(number) or number != int(number):
                    raise bad
                number = int(number)
            elif self.finite and not math.isfinite(number):
                raise ExabricksError(f"{self.keyword}: values must be finite numbers, got {value!r}")
            elif self.finite:
                check_float32(number, self.keyword)
            lo, hi = self.low, self.high
            if (lo is not None and (number < lo or (self.low_open and number == lo))) or \
                    (hi is not None and (number > hi or (self.high_open and number == hi))):
                raise bad
            return number
        if kind == "choice":
            if value not in self.choices:
                raise bad
            return value
        if kind == "flag":
            if not isinstance(value, bool):
                raise bad
            return value
        if kind == "numbers":
            values = value.split(",") if isinstance(value, str) else value
            try:
                values = tuple(float(v) for v in values)
            except (TypeError, ValueError):
                raise bad from None
            if (self.counts is not None and len(values) not in self.counts) or \
                    not all(0.0 <= v <= 1.0 for v in values):
                raise bad
            return values
        if kind == "size":
            from ..util.sizes import parse_size

            return parse_size(value)
        if kind == "file":
            why = not_regular(value) if isinstance(value, (str, os.PathLike)) else "not a path"
            if why is not None:
                raise ExabricksError(f"{self.keyword}: expected a regular file, got {value!r} "
                                     f"({why})")
            return os.fspath(value)
        if not isinstance(value, (str, os.PathLike)):
            raise bad
        return os.fspath(value)

    def _expected(self) -> str:
        if self.kind in ("float", "int"):
            return self._words()
        if self.kind == "choice":
            return _one_of(self.choices)
        if self.kind == "flag":
            return "True or False"
        if self.kind == "plane":
            return "an axis (x, y or z) and a finite position"
        if self.kind == "numbers":
            n = " or ".join(map(str, self.counts)) if self.counts else "any number of"
            return f"{n} numbers in [0, 1]"
        return "a string"

    def schema(self) -> dict:
        """The JSON Schema node of the option's value in a scene file."""
        if self.kind == "choice":
            return {"description": self.description or _one_of(self.choices),
                    "enum": list(self.choices)}
        if self.kind == "flag":
            return {"description": self.description or "true or false", "type": "boolean"}
        if self.kind == "numbers" and self.counts and len(self.counts) == 1:  # a colour
            return {"description": self.description or f"a list of {self.counts[0]} numbers in [0, 1]",
                    "type": "array", "minItems": self.counts[0], "maxItems": self.counts[0],
                    "items": {"type": "number", "minimum": 0, "maximum": 1}}
        if self.nargs > 1:  # a vector of float32 numbers
            return {"description": self.description or f"a list of {self.nargs} numbers",
                    "type": "array", "minItems": self.nargs, "maxItems": self.nargs,
                    "items": {"type": "number", "minimum": -FLOAT32_MAX, "maximum": FLOAT32_MAX}}
        node = {"type": {"float": "number", "int": "integer"}[self.kind]}
        low, high = self.low, self.high
        if self.kind == "float" and self.finite:
            low = -FLOAT32_MAX if low is None else low
            high = FLOAT32_MAX if high is None else high
        if low is not None:
            node["exclusiveMinimum" if self.low_open else "minimum"] = low
        if high is not None:
            node["exclusiveMaximum" if self.high_open else "maximum"] = high
        return {"description": self.description or self._words(), **node}

    def _words(self) -> str:
        lo, hi = self.low, self.high
        if self.kind == "int":
            return f"an integer from {lo} to {hi}"
        if lo is not None and hi is not None:
            return (f"a number in {'(' if self.low_open else '['}{lo:g}, {hi:g}"
                    f"{')' if self.high_open else ']'}")
        if lo == 0 and self.low_open:
            return "a positive number"
        if lo is not None:
            return f"a number {'>' if self.low_open else '>='} {lo:g}"
        return "a number"


def float32_problem(number: float) -> str | None:
    """Why `number` cannot be a float32 setting of the kernels, or None when it can."""
    if abs(number) > FLOAT32_MAX:
        return f"{number:g} is beyond the float32 range (magnitude at most {FLOAT32_MAX:.6g})"
    return None


def check_float32(number: float, keyword: str) -> None:
    """ExabricksError naming `keyword` when `number` overflows the kernels' float32."""
    why = float32_problem(number)
    if why is not None:
        raise ExabricksError(f"{keyword}: {why}")


def _one_of(choices) -> str:
    quoted = [f'"{c}"' for c in choices]
    return " or ".join(quoted) if len(quoted) == 2 else f"one of {', '.join(quoted)}"


def _vector(name, help, nargs=3, metavar="X Y Z", **kw) -> Option:
    return Option(name, help, nargs=nargs, metavar=metavar, **kw)


_POSITIVE = {"low": 0.0, "low_open": True}
_AO = ("ambient_occlusion",)  # where the ambient-occlusion settings sit in "lighting"
_LIGHT = ("light",)  # where the directional light's settings sit in "lighting"
_PATH = ("path",)  # where the path integrator's settings sit in "lighting"


def _setting(name, help, **kw) -> Option:
    """An attribute of Settings, at the top level of the scene file."""
    return Option(name, help, target=f"settings.{name}", **kw)


def _light(name, help, within=(), **kw) -> Option:
    """An attribute of Lighting, in the scene file's "lighting" object (`within` it).
    The file's key is the attribute's name less its "ao_" prefix inside _AO, less
    "light_" inside _LIGHT, where `light` itself is the "direction"."""
    key = name[3:] if within == _AO else name
    if within == _LIGHT:
        key = name[len("light_"):] if name != "light" else "direction"
    return Option(name, help, target=f"lighting.{name}", scene_key=("lighting", *within, key), **kw)

SCENE_OPTIONS = (
    _vector("position", "Camera position (world units).", finite=False),
    _vector("look_at", "Point the camera looks at (world units).", finite=False),
    _vector("up", "Camera up vector.", finite=False),
    Option("fovy", "Full vertical field of view, degrees."),
    Option("field", "Scalar field to use (default: the density where the data has one, "
           "else the first field that is not embedded-boundary geometry such as vfrac).",
           kind="text", metavar="NAME"),
    Option("scale", "The field's axis for the transfer function and colour bar: auto (default: "
           "log for a positive field spanning more than two decades, else linear), linear, log "
           "or symlog.", kind="choice", choices=SCALES),
    Option("transfer_function", "ParaView colour-map preset JSON, or a built-in name (default, "
           "inferno-shells; built-ins are stretched over --range or the field's range).",
           kind="text", metavar="PRESET"),
    Option("colormap", "A matplotlib colormap over --range (default: the field's range); without "
           "--opacity, with the automatic opacity (docs/scene.md).", kind="text", metavar="NAME"),
    Option("range", "Data range of the colormap (and rescales a preset file to it).", nargs=2,
           metavar="LO HI"),
    Option("opacity", "With --colormap: alpha knots spread evenly over the range (default 0,1: "
           "a ramp).", kind="numbers", metavar="A0,A1,..."),
    Option("volume", "Draw the volume layers (default) or none. --field, --transfer-function, "
           "--colormap, --range, --opacity replace the scene's layers by the one they describe.",
           kind="flag"),
    Option("iso", "Iso-surface of --field (default: the first volume field) at VALUE; repeatable; "
           "replaces the scene's iso-surfaces.", multiple=True, metavar="VALUE"),
    Option("iso_color", "Colour of the iso-surfaces, in [0, 1] (default 0.9,0.9,0.9).",
           kind="numbers", counts=(3,), metavar="R,G,B"),
    Option("iso_opacity", "Opacity of the iso-surfaces (default 1).", low=0.0, high=1.0,
           metavar="A"),
    Option("iso_color_field", "Colour the iso-surfaces by this field.", kind="text", metavar="NAME"),
    Option("iso_colormap", "Colormap of --iso-color-field (default viridis).", kind="text",
           metavar="NAME"),
    _vector("iso_range", "Data range of --iso-colormap (default: the colour field's range).",
            nargs=2, metavar="LO HI"),
    _vector("slice", "A slice of --field through point P with normal N (world units); repeatable; "
            "replaces the scene's slices.", nargs=6, metavar="PX PY PZ NX NY NZ", multiple=True),
    Option("slice_colormap", "Colormap of the slices (default viridis).", kind="text",
           metavar="NAME"),
    _vector("slice_range", "Data range of --slice-colormap (default: the slice field's range).",
            nargs=2, metavar="LO HI"),
    Option("mesh", "A triangle mesh (OBJ, PLY or STL, world units) drawn with the volume; "
           "repeatable; replaces the scene's meshes.", kind="file", multiple=True, metavar="FILE"),
    Option("mesh_color", "Colour of the meshes, in [0, 1] (default 0.9,0.9,0.9).",
           kind="numbers", counts=(3,), metavar="R,G,B"),
    Option("mesh_color_field", "Colour the meshes by this field at the hit (viridis over its "
           "range; the fixed colour where it has no data).", kind="text", metavar="NAME"),
    Option("mesh_opacity", "Opacity of the meshes (default 1).", low=0.0, high=1.0, metavar="A"),
    Option("mirror", "Draw the data and the meshes with their mirror image across the plane "
           "AXIS = POSITION (AXIS: x, y or z; world units); repeatable; replaces the scene's "
           "instances.", kind="plane", nargs=2, multiple=True, metavar="AXIS POSITION"),
    _vector("clip_box", "Keep only the inside of this box.", nargs=6, metavar="X0 Y0 Z0 X1 Y1 Z1"),
    _vector("clip_plane", "Keep only the half-space (p - P).N >= 0; repeatable; replaces the "
            "scene's planes.", nargs=6, metavar="PX PY PZ NX NY NZ", multiple=True),
    _light("shading", "headlight (default): diffuse (+ --specular) light from the camera; none: "
           "emission-absorption only.", kind="choice", choices=SHADING_MODES,
           applies=("headlight",)),
    _setting("reconstruction", "basis (default): the paper's continuous blend of cells; nearest: "
             "the value of the containing leaf cell; vertex: trilinear in stitched vertex values.",
             kind="choice", choices=RECONSTRUCTIONS),
    _setting("lod", "Level of detail: sample each region at the coarsest level whose cells "
             "project to at most PIXELS pixels (default 0: full resolution).", low=0.0,
             metavar="PIXELS", description="a number of pixels >= 0 (0: full resolution)"),
    _setting("tf_lookup", "table (default): volume transfer functions read from a table, the "
             "exact function where the knots lie on its nodes (every built-in preset and "
             "colormap), else within 1/1024 (docs/design.md); exact: from the knots.",
             kind="choice", choices=TF_LOOKUPS),
    _light("gradient", "Normals from the analytic gradient (default) or central differences.",
           kind="choice", choices=GRADIENTS, applies=("shaded",)),
    _light("iso_gradient", "Normals of iso-surfaces from central differences of the "
           "reconstructed field (default; computed at hits only) or the analytic gradient.",
           kind="choice", choices=GRADIENTS, kernel=True, applies=("surfaces",)),
    _light("specular", "Blinn-Phong specular weight on surfaces (default 0).", low=0.0,
           kernel=True, applies=("surfaces",)),
    _light("shininess", "Blinn-Phong exponent (default 32).", **_POSITIVE, kernel=True,
           applies=("surfaces",)),
    _light("ao_samples", "Ambient-occlusion rays per surface hit (default 0: off).", _AO, kind="int",
           low=0, high=MAX_AO_SAMPLES, applies=("surfaces",)),
    _light("ao_distance", "Length of the ambient-occlusion rays, world units (default: 10 finest "
           "cell widths).", _AO, **_POSITIVE, applies=("surfaces",)),
    _light("integrator", "headlight (default): light from the camera (--shading); shadow: a "
           "directional light (--light) whose transmittance through the volume and the surfaces "
           "lights every sample, plus --ambient; path: volumetric path tracing of the volume "
           "layers and the surfaces under the same lights, with multiple scattering (--bounces, "
           "--anisotropy; converges with --spp).", kind="choice", choices=INTEGRATORS),
    _light("shadow_rays", "With --integrator shadow: the volume's transmittance toward the light "
           "cached once per light, transfer function and dataset, in a light-space volume that "
           "every frame reads (cached, the default; iso-surfaces, slices and meshes keep their "
           "exact shadow rays), or traced by a shadow ray from every sample (traced: the "
           "reference, many times slower).", kind="choice", choices=SHADOW_RAYS,
           applies=("shadow",)),
    _light("bounces", "With --integrator path: scattering events of a path at most (default 8; "
           "1: single scattering), with Russian roulette from the third.", _PATH, kind="int",
           low=1, high=MAX_BOUNCES, kernel=True, applies=("path",)),
    _light("anisotropy", "With --integrator path: the Henyey-Greenstein phase function's g, "
           "from -0.99 (back-scattering) to 0.99 (forward; default 0: isotropic).", _PATH,
           low=-0.99, high=0.99, kernel=True, metavar="G", applies=("path",)),
    _light("light", "With --integrator shadow or path: the direction toward the light, world (default: "
           "the camera's key light, 35 degrees above the view and 60 to its left).", _LIGHT, nargs=3,
           metavar="DX DY DZ", description="[dx, dy, dz], a direction toward the light (not zero)",
           applies=("light",)),
    _light("light_color", "Colour of the light, in [0, 1] (default 1,1,1).", _LIGHT, kind="numbers",
           counts=(3,), metavar="R,G,B", applies=("light",)),
    _light("light_intensity", "Intensity of the light (default 0.8: with --ambient 0.2, a surface "
           "facing an unshadowed light is as bright as under the headlight).", _LIGHT, low=0.0,
           metavar="I", applies=("light",)),
    _light("ambient", "With --integrator shadow: light that reaches every sample whatever the "
           "shadows; with path: the radiance of a uniform environment (default 0.2).", low=0.0,
           metavar="A", applies=("light",)),
    Option("background", "Background colour in [0, 1] (RGB is opaque; default transparent in "
           ".exr, black behind a .png).", kind="numbers", counts=(3, 4), metavar="R,G,B[,A]"),
    _setting("exposure", "Scale the frame's colour by 2**STOPS before the background (the film, "
             "docs/design.md; default 0). Exact under every way of drawing a frame: tiles, "
             "--memory-budget, MPI, instances.", low=-24.0, high=24.0, metavar="STOPS",
             description="a number of stops in [-24, 24] (0: as integrated)"),
    _setting("auto_exposure", "Bring the frame to the display's range as yt normalises its "
             "images: the 99th percentile of the luminance over the data placed near white, "
             "measured on the frame itself (the film, docs/scene.md \"Exposure\"; --exposure "
             "adds to it). Default: on where every volume's transfer function is the automatic "
             "one, off where you chose the colours and opacities.", kind="flag"),
    _setting("denoise", "Denoise the frame for a preview with Intel Open Image Denoise "
             "(pip install 'exabricks[denoise]'; whole frames, not --tile). Never for a reference "
             "image: the error is then the network's, not the integrator's (default off).",
             kind="flag"),
    _setting("transparent", "A .png keeps the frame's alpha (un-premultiplied colour) instead of "
             "being composited over the background made opaque (default; black behind a "
             "transparent background).", kind="flag"),
    _setting("unit_distance", "World thickness over which alpha is the opacity (default: the finest "
             "cell width).", **_POSITIVE),
    Option("size", "Image size in pixels (default 512 512).", kind="int", nargs=2, low=1,
           high=32768, metavar="W H"),
    _setting("spp", "Samples per pixel (default 1).", kind="int", low=1, high=4096),
    _setting("seed", "Seed of the interleaved jitter and sub-pixel positions (default 0).",
             kind="int", low=0, high=2**32 - 1),
    _setting("jitter", "--no-jitter: no interleaved jitter (rho = 0.5): fully deterministic sample "
             "positions.", kind="flag", applies=("marched",)),
    _setting("sampling_rate", "Samples per finest cell width of each region (default 2; 4 "
             "where every volume's transfer function is the automatic one).",
             **_POSITIVE),
    _setting("max_opacity", "Early ray termination threshold (default 0.98; 1 turns it off).",
             low=0.0, high=1.0, low_open=True, applies=("marched",)),
    _setting("depth", "Add a depth channel Z (.exr only): distance to the first opaque surface, "
             "else where the opacity reaches 0.5.", kind="flag"),
)

# The names `scene_from_options` takes (None, or an empty tuple, means "not given").
FLAGS = tuple(o.name for o in SCENE_OPTIONS)
# The flags that describe one volume layer (they replace the scene file's layers).
VOLUME_FLAGS = ("field", "transfer_function", "colormap", "range", "opacity", "scale")

JOB_OPTIONS = (
    Option("scene", "Scene JSON (docs/scene.md): camera, volumes, iso-surfaces, slices, clipping, "
           "lighting, background and settings. Flags override it.", kind="file",
           dest="scene_path"),
    Option("camera", 'Camera JSON {"position", "look_at", "up", "fovy"} (world units; default: '
           "the scene's, else a three-quarter view of the whole dataset).", kind="file",
           dest="camera_path"),
    Option("camera_path", "Camera-path JSON (`exabricks camera orbit|path`): draw its frame(s) "
           "given by --frame or --frames; -o then names frame I by a printf field, e.g. "
           "frame_%05d.png.", kind="file", dest="path_file"),
    Option("frame", "With --camera-path: frame I (from 0; negative counts from the end).",
           kind="text", metavar="I"),
    Option("frames", "With --camera-path: frames A to B-1 (Python slice; 'A:' to the end), one "
           "upload, one image each.", kind="text", metavar="A:B"),
    Option("mpi_mode", "Under mpiexec/srun with several ranks: data splits the dataset by space "
           "(each rank holds a domain; sort-last compositing), image replicates it and splits the "
           "frame (faster for data that fits every rank).", kind="choice",
           choices=("data", "image"), default="data"),
    Option("memory_budget", "Render within SIZE bytes of memory, host and device (e.g. 2G, "
           "512MiB, 1500000000; K/M/G/T and KiB..TiB are powers of 1024, kB/MB/GB/TB of 1000; "
           "also $EXABRICKS_MEMORY_BUDGET): data that does not fit is cut into domains by space "
           "and streamed from the files, one domain at a time, for the same image.", kind="size",
           envvar="EXABRICKS_MEMORY_BUDGET", metavar="SIZE", dest="budget"),
    Option("progressive", "Rewrite the output every SECONDS with the image so far (domains front "
           "to back, then more samples per pixel); each rewrite is a whole image.", **_POSITIVE,
           metavar="SECONDS"),
    Option("time_limit", "Stop refining a frame after SECONDS (the first frame counts from the "
           "start of the command) and write the best image so far; its metadata "
           "(settings.progress) says what it covers.", **_POSITIVE, metavar="SECONDS"),
    Option("annotate", "Draw a .png with colour bars (the volume's with its opacity curve), field "
           "names and units, the simulation time, a scale bar and an axes triad beside the frame "
           "(docs/annotate.md); an .exr stays the raw integration.", kind="flag"),
    Option("title", f"With --annotate: a title above the frame (one line, at most "
           f"{MAX_TITLE_CHARS} characters).", kind="text", metavar="TEXT"),
    Option("tile", "Draw the frame in tiles of W x H pixels, a row of tiles at a time, each "
           "written to the output file as it is done: only a band of H rows is ever in memory "
           "(posters far larger than memory; with --memory-budget the budget counts the band, "
           "not the frame).", kind="int", nargs=2, low=1, high=32768, metavar="W H"),
)


def flag_name(name: str) -> str:
    """The command-line flag of option `name` ("look_at" -> "--look-at")."""
    return "--" + name.replace("_", "-")


def normalised_flags(flags: dict | None) -> dict:
    """`flags` with every name of FLAGS present (None: not given); TypeError for an
    unknown name."""
    out = dict.fromkeys(FLAGS)
    for name, value in (flags or {}).items():
        if name not in out:
            raise TypeError(f"unknown flag {name!r} (one of {', '.join(FLAGS)})")
        if isinstance(value, (tuple, list)) and len(value) == 0:
            value = None  # click's value of a repeatable option that was not given
        out[name] = value
    return out


def check_flags(flags: dict) -> None:
    """ExabricksError for flags that contradict each other whatever the scene file
    says (the CLI reports it as a usage error)."""
    f = normalised_flags(flags)
    if f["transfer_function"] is not None and f["colormap"] is not None:
        raise ExabricksError("give --transfer-function or --colormap, not both")
    if f["opacity"] is not None and f["colormap"] is None:
        raise ExabricksError("--opacity goes with --colormap")
    if f["volume"] is False:
        for name in VOLUME_FLAGS[1:]:
            if f[name] is not None:
                raise ExabricksError(f"{flag_name(name)} describes a volume layer, but --no-volume draws none")
    if f["iso_color"] is not None and f["iso_color_field"] is not None:
        raise ExabricksError("give --iso-color or --iso-color-field, not both")
    if f["mesh_color"] is not None and f["mesh_color_field"] is not None:
        raise ExabricksError("give --mesh-color or --mesh-color-field, not both")
    for name in ("iso_colormap", "iso_range"):
        if f[name] is not None and f["iso_color"] is not None:
            raise ExabricksError(f"{flag_name(name)} goes with --iso-color-field, not --iso-color")
