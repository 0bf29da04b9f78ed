"""`exabricks info FILE`: kind, version, counts, fields, world bounds of any exabricks
file; format, time, levels, cells per level, fields and their ranges, world bounds
of any source (exabricks.describe)."""

from __future__ import annotations

import json

import click

from .options import ingest_given, ingest_kwargs, ingest_options


@click.command()
@click.argument("paths", metavar="FILE...", nargs=-1, required=True, type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (keys: docs/file-formats.md).")
@click.option("--field-range", metavar="FIELD",
              help="Print only 'LO HI', the range of FIELD over all the FILEs (a time series' "
                   "fixed transfer-function range: render --range $(exabricks info --field-range ...)).")
@ingest_options("--fields", leave_out=("nan_policy",))
def info(paths, as_json, field_range, **options):
    """Summarise exabricks .npz files (cells, bricks, regions, bvh or values) or
    sources (anything `render SOURCE` takes, read with the ingest options given, as
    that render reads it; non-finite values are kept and counted)."""
    from ..describe import describe, field_range as range_of

    given = ingest_given(ingest_kwargs(options))
    if field_range is not None:
        click.echo(" ".join(f"{v!r}" for v in range_of(paths, field_range, given)))
        return
    for path in paths:
        s = describe(path, given)
        if as_json:
            click.echo(json.dumps(s, indent=2, sort_keys=True, allow_nan=False))
        elif s["kind"] == "source":
            _show_source(s)
        else:
            _show(s)


def _show_source(s) -> None:
    about = s["source"].get("code") or s["source"].get("frontend")
    click.echo(f"{s['path']}: {s['format']} source" + (f" ({about})" if about else ""))
    if s["time"] is not None:
        click.echo(f"  time: {s['time']!r}")
    click.echo(f"  levels: {s['levels']} (level 0 is the finest)")
    click.echo(f"  cells: {s['counts']['cells']:,}")
    for level, n in s["counts"]["cells_per_level"].items():
        click.echo(f"  level {level}: {n:,} cells of width {s['cell_width_per_level'][level]}")
    for f in s["fields"]:
        units = f" {f['units']}" if f.get("units") else ""
        bad = f" ({f['nonfinite']:,} non-finite)" if f["nonfinite"] else ""
        click.echo(f"  field {f['name']}: [{f['min']!r}, {f['max']!r}]{units}{bad}")
    b = s["world_bounds"]
    click.echo(f"  world bounds: {b['lower']} .. {b['upper']}")
    if s["masked"]:
        click.echo(f"  masked cells ({s['masked']['field']} == 0): {s['masked']['cells']:,}")


def _show(s) -> None:
    click.echo(f"{s['path']}: {s['kind']} (version {s['version']})")
    for key, value in s["counts"].items():
        if isinstance(value, dict):
            value = ", ".join(f"level {k}: {v:,}" for k, v in value.items())
        else:
            value = f"{value:,}"
        click.echo(f"  {key.replace('_', ' ')}: {value}")
    for f in s["fields"]:
        click.echo(f"  field {f['name']}: [{f['min']}, {f['max']}]")
    b = s["world_bounds"]
    if b["lower"]:  # a values file has none: its bricks have them
        click.echo(f"  world bounds: {b['lower']} .. {b['upper']}")
    click.echo(f"  origin: {s['origin']}  spacing: {s['spacing']}")
    stats = s["meta"].get("statistics") or {}
    for key, value in stats.items():
        click.echo(f"  {key.replace('_', ' ')}: {json.dumps(value)}")
    total = sum(s["bytes"].values())
    click.echo(f"  array bytes: {total:,}")
