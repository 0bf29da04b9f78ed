"""`exabricks info FILE`: kind, version, counts, fields, world bounds of any exabricks file."""

from __future__ import annotations

import json

import click

from .. import schema


@click.command()
@click.argument("paths", metavar="FILE...", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (keys: docs/file-formats.md).")
@click.option("--field-range", metavar="FIELD",
              help="Print only 'LO HI', the range of FIELD over all the FILEs (a time series' "
                   "fixed transfer-function range: render --range $(exabricks info --field-range ...)).")
def info(paths, as_json, field_range):
    """Summarise exabricks .npz files (cells, bricks, regions, bvh or values)."""
    if field_range is not None:
        click.echo(" ".join(f"{v!r}" for v in series_range(paths, field_range)))
        return
    for path in paths:
        _show(path, as_json)


def series_range(paths, field: str) -> tuple[float, float]:
    """(min, max) of `field` over every file of `paths` (their finite values)."""
    from ..errors import ExabricksError

    lo, hi = float("inf"), float("-inf")
    for path in paths:
        s = schema.summary(schema.load(path))
        entry = next((f for f in s["fields"] if f["name"] == field), None)
        if entry is None:
            names = ", ".join(f["name"] for f in s["fields"]) or "none"
            raise ExabricksError(f"{path}: no field {field!r} (fields: {names})")
        if entry["min"] is not None:
            lo, hi = min(lo, entry["min"]), max(hi, entry["max"])
    if lo > hi:
        raise ExabricksError(f"{paths[0]}: field {field!r} has no finite value in any file")
    return lo, hi


def _show(path, as_json) -> None:
    s = schema.summary(schema.load(path))
    s["path"] = path
    if as_json:
        click.echo(json.dumps(s, indent=2, sort_keys=True))
        return
    click.echo(f"{path}: {s['kind']} (version {s['version']})")
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
