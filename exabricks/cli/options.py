"""Options shared by several commands, defined once so they mean the same everywhere."""

from __future__ import annotations

import math

import click

from ..util.errors import ExabricksError
from ..scene.modes import AXES
from ..scene.options import SCENE_OPTIONS, float32_problem

output_option = click.option(
    "-o", "--output", "output", required=True, type=click.Path(dir_okay=False),
    help="Output file (written atomically: a failed run leaves nothing behind).",
)


device_option = click.option(
    "--device", "device", default=None, envvar="EXABRICKS_DEVICE", metavar="SPEC",
    help="OpenCL device: 'PLATFORM:DEVICE' indices, or a substring of the device or "
    "platform name (also EXABRICKS_DEVICE). Default: the first GPU, else the first CPU. "
    "`exabricks devices` lists them.",
)


def input_path(name: str, **kw):
    """A positional input file that must exist (click reports a missing one)."""
    return click.argument(name, type=click.Path(exists=True, dir_okay=False), **kw)


def finite(ctx, param, value):
    """Refuse NaN, infinities and values beyond float32's range (the kernels read
    float32) in float options (single, nargs or repeatable)."""
    flat = value if isinstance(value, tuple) else (value,)
    flat = [x for v in flat for x in (v if isinstance(v, tuple) else (v,)) if isinstance(x, float)]
    if any(not math.isfinite(x) for x in flat):
        raise click.BadParameter("values must be finite numbers")
    for x in flat:
        why = float32_problem(x)
        if why is not None:
            raise click.BadParameter(why)
    return value


def _fps(ctx, param, value):
    """Callback: a movie's frames per second, in the range both encoders take
    (exabricks.stages.movie.fps_problem), refused before anything is drawn."""
    from ..stages.movie import fps_problem

    problem = fps_problem(value)
    if problem is not None:
        raise click.BadParameter(problem)
    return value


def fps_option(default: float):
    """--fps of `movie` and `series`."""
    return click.option("--fps", type=float, default=default, show_default=True, callback=_fps,
                        help="Frames per second of the movie (0.01 to 1000).")


def size(ctx, param, text):
    """Callback: a size in bytes ("2G", "512MiB"; exabricks.util.sizes.parse_size)."""
    if text is None:
        return None
    from ..util.sizes import parse_size

    try:
        return parse_size(text)
    except ExabricksError as e:
        raise click.BadParameter(str(e)) from None


def numbers(counts=None, low=0.0, high=1.0):
    """Callback: comma-separated numbers in [low, high], as many as one of `counts`
    (None: any number)."""
    def parse(ctx, param, text):
        if text is None:
            return None
        try:
            values = tuple(float(a) for a in text.split(","))
        except ValueError:
            raise click.BadParameter(f"{text!r} is not a comma-separated list of numbers") from None
        if counts is not None and len(values) not in counts:
            raise click.BadParameter(f"expected {' or '.join(map(str, counts))} numbers, got {text!r}")
        if not all(low <= a <= high for a in values):
            raise click.BadParameter(f"values must lie in [{low:g}, {high:g}], got {text}")
        return values
    return parse


def _piece(ctx, param, text):
    """Callback: "K/N" as a Piece (WHOLE when not given)."""
    from ..formats.pieces import WHOLE, Piece

    if text is None:
        return WHOLE
    try:
        return Piece.parse(text)
    except ExabricksError as e:
        raise click.BadParameter(str(e)) from None


piece_option = click.option(
    "--piece", "piece", default=None, metavar="K/N", callback=_piece,
    help="Build only piece K of N (from 0), e.g. a SLURM array task's "
    "($SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT); `exabricks join` puts the N pieces "
    "together into what one process builds.",
)


def declared(*options):
    """A decorator adding the click options of `options` (exabricks.scene.options.Option,
    the one declaration of each render option), in their order."""
    def apply(command):
        for option in reversed(options):
            command = _click_option(option)(command)
        return command
    return apply


def _click_option(o):
    """The click option of one declared Option."""
    kw = {"help": o.help, "metavar": o.metavar, "default": o.default, "nargs": o.nargs,
          "multiple": o.multiple, "envvar": o.envvar}
    bounded = o.low is not None or o.high is not None
    if o.kind == "float":
        kw["type"] = click.FloatRange(o.low, o.high, min_open=o.low_open,
                                      max_open=o.high_open) if bounded else float
        kw["callback"] = finite if o.finite else None
    elif o.kind == "int":
        kw["type"] = click.IntRange(o.low, o.high) if bounded else int
    elif o.kind == "file":
        kw["type"] = click.Path(exists=True, dir_okay=False)
    elif o.kind == "choice":
        kw["type"] = click.Choice(o.choices)
        kw["show_default"] = o.default is not None
    elif o.kind == "plane":
        kw["type"] = (click.Choice(AXES), float)
        kw["callback"] = finite
    elif o.kind == "numbers":
        kw["callback"] = numbers(o.counts)
    elif o.kind == "size":
        kw["callback"] = size
    elif o.kind == "flag":
        return click.option(f"{o.flag}/--no-{o.flag[2:]}", o.keyword, default=None, help=o.help)
    elif o.kind != "text":
        raise ValueError(f"unknown option kind {o.kind!r} of {o.name}")
    return click.option(o.flag, o.keyword, **{k: v for k, v in kw.items() if v is not None})


# --field of render, probe and the viewer: the render option's one declaration.
field_option = declared(*(o for o in SCENE_OPTIONS if o.name == "field"))


# ---------------------------------------------------------------------------
# ingest's options: of `ingest`, and of the commands that take a source
# (render, probe), which build through ingest with them.


def _name_equals(kind: str):
    def convert(ctx, param, values):
        out = []
        for v in values:
            key, sep, rest = v.partition("=")
            if not sep or not key or not rest:
                raise click.BadParameter(f"{v!r} is not {kind}", ctx=ctx, param=param)
            out.append((key, rest))
        return tuple(out)
    return convert


def _names(ctx, param, values):
    """Repeatable, comma-separated names, in order."""
    return tuple(n for v in values for n in v.split(",") if n)


def _pairs_dict(kind: str):
    """Callback: NAME=VALUE pairs as a dict, None when none is given."""
    pairs = _name_equals(kind)
    return lambda ctx, param, values: dict(pairs(ctx, param, values)) or None


def _ingest_table(field_flags=("--field", "--fields")) -> list[tuple[str, tuple, dict]]:
    """(the ingest stage's keyword, flags, click settings) of every ingest option: their
    one declaration; `field_flags` name the field selection (`ingest --field`;
    `--fields` where `--field` is the rendered field)."""
    from ..util.constants import AUTO_MASK_FIELD, NAN_POLICIES
    from ..readers import FORMATS
    from ..readers.raw import BYTE_ORDERS, DTYPES

    return [
        ("format", ("--format",), dict(type=click.Choice(("auto", *FORMATS)), default="auto",
                                       show_default=True, help="Input format; auto tells it from the path.")),
        ("fields", field_flags, dict(multiple=True, metavar="NAME[,NAME...]", callback=_names,
                                     help="Keep only these fields (repeatable; default: all fields of "
                                     "the input).")),
        ("scalars", ("--scalars",), dict(multiple=True, metavar="NAME=FILE", callback=_pairs_dict("NAME=FILE"),
                                         help="exajet: field NAME from FILE (repeatable; default: the "
                                         "STEM.NAME.scalars siblings).")),
        ("dims", ("--dims",), dict(nargs=3, type=click.IntRange(min=1), default=None, metavar="X Y Z",
                                   help="raw: voxels per axis, x fastest in the file.")),
        ("dtype", ("--dtype",), dict(type=click.Choice(DTYPES), default="float32", show_default=True,
                                     help="raw: voxel type.")),
        ("byte_order", ("--byte-order",), dict(type=click.Choice(tuple(BYTE_ORDERS)), default="little",
                                               show_default=True, help="raw: byte order of the voxels.")),
        ("name", ("--name",), dict(default="value", show_default=True, help="raw: field name.")),
        ("max_level", ("--max-level",), dict(type=click.IntRange(min=0), default=None,
                                             help="raw: coarsest level to merge to [default: as coarse "
                                             "as the dims allow].")),
        ("threshold", ("--threshold",), dict(type=click.FloatRange(min=0), callback=finite, default=0.0,
                                             show_default=True, help="raw: a 2x2x2 group merges when "
                                             "max - min of its voxels is at most this (absolute, in data "
                                             "units).")),
        ("magnitude", ("--magnitude",), dict(multiple=True, metavar="NAME=A,B,C",
                                             callback=_name_equals("NAME=A,B,C"),
                                             help="Add field NAME = |(A, B, C)| from component fields "
                                             "(repeatable).")),
        ("derive", ("--derive",), dict(multiple=True, metavar="NAME=EXPR", callback=_name_equals("NAME=EXPR"),
                                       help="Add field NAME = EXPR, evaluated per cell over the input's "
                                       "fields (numexpr's language: + - * / **, sqrt, log, where, ...; "
                                       "docs/ingest.md; repeatable, in order).")),
        ("nan_policy", ("--nan",), dict(type=click.Choice(NAN_POLICIES), default="error",
                                        show_default=True, help="NaN/Inf values: error; zero (replace "
                                        "by 0); drop (remove those cells); keep (store unchanged).")),
        ("mask", ("--mask",), dict(default=None, metavar="FIELD",
                                   help="Drop the cells where FIELD == 0 (they become holes, e.g. the body "
                                   f"of an embedded-boundary plotfile). Default: {AUTO_MASK_FIELD} when "
                                   "the input has it.")),
        ("auto_mask", ("--no-mask",), dict(is_flag=True, flag_value=False, default=True,
                                           help=f"Keep every cell: no automatic --mask {AUTO_MASK_FIELD}.")),
    ]


def ingest_options(*field_flags: str, leave_out: tuple[str, ...] = ()):
    """A decorator adding the ingest options (`_ingest_table`), each passed under the
    ingest stage's own keyword; `leave_out`: keywords of those a command does not take."""
    options = [click.option(*flags, keyword, **settings)
               for keyword, flags, settings in _ingest_table(field_flags) if keyword not in leave_out]

    def apply(command):
        for option in reversed(options):
            command = option(command)
        return command
    return apply


def ingest_defaults() -> dict:
    """What the ingest options give when none is used (tests/library/test_source.py checks
    them against the stage's own defaults)."""
    out = {}
    for keyword, _, settings in _ingest_table():
        value = settings.get("default", () if settings.get("multiple") else None)
        callback = settings.get("callback")
        out[keyword] = callback(None, None, value) if callback else value
    return out


def ingest_kwargs(options: dict) -> dict:
    """The ingest stage's keyword arguments, popped from a command's `options` (those
    it takes: `ingest_options`' leave_out)."""
    kwargs = {keyword: options.pop(keyword) for keyword, _, _ in _ingest_table() if keyword in options}
    if kwargs["mask"] is not None and not kwargs["auto_mask"]:
        raise click.UsageError("--mask and --no-mask exclude each other")
    return kwargs


def ingest_given(kwargs: dict) -> dict:
    """Those of `ingest_kwargs`' keywords whose values are not the defaults: what a
    source's build and its cache key take."""
    defaults = ingest_defaults()
    return {k: v for k, v in kwargs.items() if v != defaults[k]}


cache_option = click.option(
    "--cache", "cache", default=None, metavar="DIR", type=click.Path(file_okay=False),
    help="Where a source's built structures are kept [default: $EXABRICKS_CACHE, else "
    "$XDG_CACHE_HOME/exabricks, else ~/.cache/exabricks].")


def dataset_arguments(command):
    """SOURCE | BRICKS REGIONS BVH, with the ingest options and the cache's (the
    commands that take a dataset: render, probe); `dataset_from` makes it."""
    command = cache_option(command)
    command = click.option(
        "--no-cache", "no_cache", is_flag=True,
        help="Build a source's structures in memory only.")(command)
    command = ingest_options("--fields")(command)
    command = click.option(
        "--values", "values", default=None, metavar="FILE", type=click.Path(exists=True, dir_okay=False),
        help="A step of a time series on these structures' cells (`exabricks values`), drawn "
        "instead of the bricks' own values; with BRICKS REGIONS BVH.")(command)
    return click.argument("inputs", nargs=-1, required=True, metavar="SOURCE | BRICKS REGIONS BVH",
                          type=click.Path(exists=True))(command)


def dataset_from(inputs, options: dict, desc: str = "build"):
    """The exabricks.dataset.Dataset of the arguments of `dataset_arguments` (their
    values popped from `options`): three structure files, or a source built with
    the ingest options given (through the cache unless --no-cache)."""
    from ..dataset import open_dataset

    cache, no_cache, values = options.pop("cache"), options.pop("no_cache"), options.pop("values")
    given = ingest_given(ingest_kwargs(options))
    if len(inputs) == 3:
        flag_of = {keyword: flags[-1] for keyword, flags, _ in _ingest_table()}
        flags = [flag_of[k] for k in given] + (["--cache"] if cache is not None else []) \
            + (["--no-cache"] if no_cache else [])
        if flags:
            raise click.UsageError(f"{', '.join(flags)}: only with a source, not with three "
                                   "structure files")
    elif len(inputs) != 1:
        raise click.UsageError(f"give one source or the three structure files BRICKS REGIONS BVH, "
                               f"not {len(inputs)} inputs")
    elif values is not None:
        raise click.UsageError("--values: with the three structure files BRICKS REGIONS BVH it was "
                               "made for, not with a source (give that step's source instead)")
    if cache is not None and no_cache:
        raise click.UsageError("--cache and --no-cache exclude each other")
    return open_dataset(inputs, given, cache=False if no_cache else cache, desc=desc, values=values)
