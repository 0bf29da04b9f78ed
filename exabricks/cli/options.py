"""Options shared by several commands, defined once so they mean the same everywhere."""

from __future__ import annotations

import click

output_option = click.option(
    "-o", "--output", "output", required=True, type=click.Path(dir_okay=False),
    help="Output file (written atomically: a failed run leaves nothing behind).",
)

field_option = click.option(
    "--field", "field", default=None, metavar="NAME",
    help="Scalar field to use (default: the first field of the file).",
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
