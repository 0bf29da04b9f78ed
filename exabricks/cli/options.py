"""Options shared by several commands, defined once so they mean the same everywhere."""

from __future__ import annotations

import math

import click

from ..errors import ExabricksError
from ..scene.options import SCENE_OPTIONS

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
    """Refuse NaN and infinities in float options (single, nargs or repeatable)."""
    flat = value if isinstance(value, tuple) else (value,)
    flat = [x for v in flat for x in (v if isinstance(v, tuple) else (v,))]
    if any(isinstance(x, float) and not math.isfinite(x) for x in flat):
        raise click.BadParameter("values must be finite numbers")
    return value


def size(ctx, param, text):
    """Callback: a size in bytes ("2G", "512MiB"; exabricks.render.streaming.parse_size)."""
    if text is None:
        return None
    from ..render.streaming import parse_size

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
    from ..pieces import WHOLE, Piece

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
