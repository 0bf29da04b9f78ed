"""`exabricks devices`: the OpenCL platforms and devices, with the specs --device takes."""

from __future__ import annotations

import json

import click


@click.command()
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def devices(as_json):
    """List OpenCL devices; pass a SPEC (P:D or a name substring) to --device."""
    from ..opencl import choose_device, list_devices

    infos = list_devices()
    default = choose_device(None)
    rows = [{**d.to_dict(), "default": d.name == default.name.strip()} for d in infos]
    if as_json:
        click.echo(json.dumps(rows, indent=2))
        return
    for r in rows:
        mark = "*" if r["default"] else " "
        click.echo(f"{mark} {r['spec']}  {r['type']:<4} {r['name']}  [{r['platform']}, {r['version']}, "
                   f"{r['compute_units']} compute units, {r['global_memory_bytes'] / 2**30:.1f} GiB]")
