"""`exabricks compare A B`: image metrics against thresholds, with diff(1)-like exit status."""

from __future__ import annotations

import json
import math

import click

from ..util.errors import ExabricksError
from ..util.output import check_output

# (metric, option flag, True if the metric must stay at or below the threshold)
THRESHOLDS = (
    ("rmse", "--max-rmse", True),
    ("psnr", "--min-psnr", False),
    ("max_abs", "--max-abs", True),
    ("ssim", "--min-ssim", False),
)


def _json_number(x):
    """JSON has no infinity: an infinite PSNR (identical images) is written as "inf"."""
    return "inf" if isinstance(x, float) and math.isinf(x) else x


@click.command()
@click.argument("image_a", metavar="A", type=click.Path(dir_okay=False))
@click.argument("image_b", metavar="B", type=click.Path(dir_okay=False))
@click.option("--max-rmse", type=float, default=None, metavar="X", help="Fail if RMSE > X.")
@click.option("--min-psnr", type=float, default=None, metavar="DB", help="Fail if PSNR < DB (peak 1.0).")
@click.option("--max-abs", type=float, default=None, metavar="X", help="Fail if any channel differs by more than X.")
@click.option("--min-ssim", type=float, default=None, metavar="X", help="Fail if mean SSIM < X.")
@click.option("--diff", "diff_path", type=click.Path(dir_okay=False), default=None, metavar="PATH",
              help="Also write a difference image (.png or .exr; grey = largest channel difference, "
              "scaled so the largest difference is white).")
@click.option("--json", "as_json", is_flag=True,
              help="Print a JSON object: a, b, width, height, rmse, psnr (\"inf\" when identical), "
              "max_abs, ssim (null under 11x11 pixels), thresholds, failed, passed.")
@click.pass_context
def compare(ctx, image_a, image_b, max_rmse, min_psnr, max_abs, min_ssim, diff_path, as_json):
    """Compare two images (.exr or .png, premultiplied RGBA) by RMSE, PSNR, max abs and SSIM.

    Exit status as diff(1): 0 if every given threshold holds, 1 if any is
    exceeded (each is named), 2 on trouble (missing or unreadable file, sizes
    that differ, a metric that cannot be computed).
    """
    from ..film.image_io import read_image, write_image
    from ..stages.compare import compare_images, diff_image

    limits = {"rmse": max_rmse, "psnr": min_psnr, "max_abs": max_abs, "ssim": min_ssim}
    for name, flag, _ in THRESHOLDS:
        if limits[name] is not None and math.isnan(limits[name]):
            raise click.BadParameter("a threshold must be a number, not nan", param_hint=flag)
    try:
        if diff_path is not None:
            check_output(diff_path, [image_a, image_b])
        a, _ = read_image(image_a)
        b, _ = read_image(image_b)
        metrics = compare_images(a, b, names=(image_a, image_b))
        if min_ssim is not None and metrics["ssim"] is None:
            raise ExabricksError(f"SSIM needs images of at least 11x11 pixels, {image_a} is {a.shape[1]}x{a.shape[0]}")
        if diff_path is not None:
            write_image(diff_path, diff_image(a, b), metadata={
                "compare": {"a": image_a, "b": image_b,
                            **{k: _json_number(v) for k, v in metrics.items()}},
            }, inputs=[image_a, image_b])
    except ExabricksError as e:
        from ..util.errors import one_line

        click.echo(f"error: {one_line(str(e))}", err=True)
        ctx.exit(2)

    failed = []
    for name, flag, upper in THRESHOLDS:
        limit = limits[name]
        if limit is None:
            continue
        value = metrics[name]
        if (value > limit) if upper else (value < limit):
            failed.append((name, flag, value, limit))

    if as_json:
        click.echo(json.dumps({
            "a": image_a, "b": image_b, "width": int(a.shape[1]), "height": int(a.shape[0]),
            **{k: _json_number(v) for k, v in metrics.items()},
            "thresholds": {flag.lstrip("-").replace("-", "_"): limits[name]
                           for name, flag, _ in THRESHOLDS if limits[name] is not None},
            "failed": [name for name, *_ in failed],
            "passed": not failed,
        }, indent=2))
    else:
        ssim = metrics["ssim"]
        click.echo(f"rmse     {metrics['rmse']:.6g}")
        click.echo(f"psnr     {metrics['psnr']:.6g} dB")
        click.echo(f"max_abs  {metrics['max_abs']:.6g}")
        click.echo(f"ssim     {'n/a (under 11x11 pixels)' if ssim is None else f'{ssim:.6g}'}")
        for name, flag, value, limit in failed:
            click.echo(f"FAIL {name} {value:.6g} {'>' if flag.startswith('--max') else '<'} {flag} {limit:g}")
    if failed:
        ctx.exit(1)
