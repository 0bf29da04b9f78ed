"""`exabricks devices`: the OpenCL platforms and devices, with the specs --device takes;
`--warm` builds the kernels of the first pictures ahead (exabricks.warm)."""

from __future__ import annotations

import json

import click

from ..warm import SETS
from .options import device_option


@click.command()
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@click.option("--warm", type=click.Choice(SETS), is_flag=False, flag_value="first", default=None,
              help="Also build the renderer's kernels on the device (--device; once per machine: "
              "the driver caches them): `first` (--warm alone) those of the first pictures (the "
              "default render, make demo's, the viewer's level of detail, the first shadow and "
              "path frames), `all` every program a frame of one field can reach.")
@device_option
def devices(as_json, warm, device):
    """List OpenCL devices; pass a SPEC (P:D or a name substring) to --device.
    The first line says where the drivers come from, and why."""
    from ..device.opencl import choose_device, list_devices
    from ..device.runtime import prepare

    runtime = prepare()
    if not as_json:  # first, also when no device is found: the runtime tells why
        click.echo(f"OpenCL runtime: {runtime.why} ({runtime.detail})")
    infos = list_devices()
    default = choose_device(None)
    rows = [{**d.to_dict(), "default": d.name == default.name.strip(), "runtime": runtime.source,
             "runtime_detail": runtime.detail} for d in infos]
    if as_json and not warm:
        click.echo(json.dumps(rows, indent=2))
        return
    if not as_json:
        for r in rows:
            mark = "*" if r["default"] else " "
            click.echo(f"{mark} {r['spec']}  {r['type']:<4} {r['name']}  [{r['platform']}, {r['version']}, "
                       f"{r['compute_units']} compute units, {r['global_memory_bytes'] / 2**30:.1f} GiB]")
    if warm:
        from ..warm import warm as warm_kernels

        target = choose_device(device).name.strip()

        def said(row):
            if not as_json:
                click.echo(f"kernels ready for {row['frame']} on {target}: {row['seconds']:.1f} s")

        warmed = warm_kernels(device, warm, on_frame=said)
        if as_json:
            for r in rows:
                if r["name"] == target:
                    r["warmed"] = warmed
            click.echo(json.dumps(rows, indent=2))
