"""`exabricks info FILE`: kind, version, counts, fields, world bounds of any exabricks file."""

from __future__ import annotations

import json

import click

from .. import schema


@click.command()
@click.argument("path", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (keys: docs/file-formats.md).")
def info(path, as_json):
    """Summarise an exabricks .npz file (cells, bricks, regions or bvh)."""
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
    click.echo(f"  world bounds: {b['lower']} .. {b['upper']}")
    click.echo(f"  origin: {s['origin']}  spacing: {s['spacing']}")
    stats = s["meta"].get("statistics") or {}
    for key, value in stats.items():
        click.echo(f"  {key.replace('_', ' ')}: {json.dumps(value)}")
    total = sum(s["bytes"].values())
    click.echo(f"  array bytes: {total:,}")
