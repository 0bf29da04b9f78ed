"""exabricks against yt, VTK, per-sample cell location and the uniform-grid ceiling.

    .venv/bin/python -m benchmarks.bench_peers [--datasets amrex,athena,gerris,enzo,shell256,big]
        [--size 1024] [--runs 5] [--no-yt] [--yt-max-cells 10000000]
        [--no-vtk] [--vtk-threads CORES]
        [--docs docs/benchmarks.md] [--images docs/images]

For every dataset the workers run one after the other, each in its own
subprocess (`python -m benchmarks.bench_peers --worker KIND SPEC RESULT`, so that
each one's peak resident memory is its own), with the same field, camera, transfer
function and image size (the shared view: benchmarks/peers/common.py). Each peer's
module says what its worker does and how that peer is matched to ours:

0. prepare (benchmarks/peers/ours.py, worker_prepare): the offline stages, timed
   but not part of any comparison; it also fixes the shared view.
1. exabricks (benchmarks/peers/ours.py, worker_exabricks): ours with the regions'
   brick lists, ours with per-sample cell location and the uniform-grid ceiling,
   their frames interleaved, at the default sampling rate 2 and at 10 samples per
   finest cell.
2. yt (benchmarks/peers/yt.py, worker_yt): yt 4.4.3's volume rendering with our
   camera and transfer function; skipped above --yt-max-cells leaf cells.
3. VTK (benchmarks/peers/vtk.py, worker_vtk): ParaView's CPU way, offscreen:
   resample to the finest grid + vtkFixedPointVolumeRayCastMapper, and
   vtkAMRVolumeMapper.

This module is the driver: it runs the workers (run_worker), compares the images
(image_agreement, side_by_side) and writes the report (benchmarks/peers/report.py).

Results: the tables on stdout and as the section "## exabricks vs yt, cell
location and the uniform-grid ceiling" of --docs (benchmarks/benchdoc.py
replace_section; the other sections stay), and docs/images/peers-NAME.png
(ours | yt | VTK resample + fixed point | vtkAMRVolumeMapper | uniform grid,
un-premultiplied over black). All timings are
provisional on a shared machine; the command is written into the section.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.peers.common import ALPHA_SCALE, DATASETS, MAX_VOXELS, RATES, ROOT
from benchmarks.peers.ours import worker_exabricks, worker_prepare
from benchmarks.peers.report import SECTION, report
from benchmarks.peers.vtk import vtk_skip_reason, worker_vtk
from benchmarks.peers.yt import YT_MAX_CELLS, worker_yt, yt_skip_reason

WORKERS = {"prepare": worker_prepare, "exabricks": worker_exabricks, "yt": worker_yt,
           "vtk": worker_vtk}


def run_worker(kind: str, spec: dict, workdir: Path) -> dict:
    """Run one worker in a subprocess; its result plus peak RSS (MiB), unless the worker
    measured its own (the exabricks worker: before the uniform grid). The worker starts
    from benchdoc's small launcher as `python -m benchmarks.bench_peers --worker KIND SPEC
    RESULT` (in the checkout), so its peak is its own and not this process's."""
    spec_path = workdir / f"{spec['name']}-{kind}-spec.json"
    result_path = workdir / f"{spec['name']}-{kind}-result.json"
    spec_path.write_text(json.dumps(spec))
    try:
        _, _, peak = benchdoc.run_child([sys.executable, "-m", "benchmarks.bench_peers", "--worker",
                                         kind, str(spec_path), str(result_path)])
    except SystemExit as e:
        return {"error": f"{kind} worker failed: {str(e).splitlines()[-1][:200]}"}
    if not result_path.is_file():
        return {"error": f"{kind} worker wrote no result"}
    result = json.loads(result_path.read_text())
    result.setdefault("peak_rss_mib", peak / 2**20)
    return result


def side_by_side(paths, out: Path, size: int) -> None:
    """ours | yt | VTK (resample + fixed point) | VTK (vtkAMRVolumeMapper) | uniform grid
    (the images at `paths`, in that order) as one PNG, each composited over black; a
    missing image is a grey tile, so the columns line up across datasets."""
    from PIL import Image

    from exabricks.film.image_io import to_png_pixels

    tiles = []
    for p in paths:
        if Path(p).is_file():
            pixels = to_png_pixels(np.load(p)).astype(np.float64)
            tiles.append(np.rint(pixels[..., :3] * pixels[..., 3:4] / 255.0).astype(np.uint8))
        else:
            tiles.append(np.full((size, size, 3), 64, np.uint8))
    gap = np.full((size, 4, 3), 255, np.uint8)
    row = np.concatenate([x for t in tiles for x in (t, gap)][:-1], axis=1)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(row).save(out)


def image_agreement(ours_path: str, other_path: str) -> dict | None:
    """compare_images metrics (rmse, psnr, max_abs, ssim) of two saved images, or None."""
    from exabricks.stages.compare import compare_images

    if not (Path(ours_path).is_file() and Path(other_path).is_file()):
        return None
    return compare_images(np.load(ours_path), np.load(other_path))


def bench_dataset(name: str, args, workdir: Path) -> dict:
    path, field, yt_mode = DATASETS[name]
    if name == "big" and not Path(path).exists():
        path = benchdoc.ensure_exajet()  # the big AMR in ExaJet form, from benchmarks/make_big.py
    if name == "shell256":
        path = benchdoc.ensure_shell(256)
    if not Path(path).exists():
        return {"name": name, "error": f"{path} missing"}
    base = {"name": name, "path": str(path), "field": field, "size": args.size, "runs": args.runs,
            "image_prefix": str(workdir / name), "max_voxels": args.max_voxels,
            "alpha_scale": args.alpha_scale}
    prep = run_worker("prepare", base, workdir)
    row = {"name": name, "field": field, "prep": prep}
    if "error" in prep:
        return row
    shared = {**base, "camera": prep["camera"], "transfer_function": prep["transfer_function"],
              "value_range": prep["value_range"], "unit_distance": prep["unit_distance"],
              "world_bounds": prep["world_bounds"]}
    row["ours"] = run_worker("exabricks", shared, workdir)
    row["uniform"] = row["ours"].pop("uniform", None)
    row["cell_location"] = row["ours"].pop("cell_location", None)
    if not args.no_yt:
        skip = yt_skip_reason(prep["cells"], args.yt_max_cells)
        row["yt"] = {"error": skip} if skip else \
            run_worker("yt", {**shared, "yt_mode": yt_mode}, workdir)
    if not args.no_vtk:
        import importlib.util

        skip = vtk_skip_reason(name, path) or (
            None if importlib.util.find_spec("vtk") else "vtk not installed (pip install vtk)")
        row["vtk"] = {"error": skip} if skip else \
            run_worker("vtk", {**shared, "vtk_threads": args.vtk_threads}, workdir)
    prefix = workdir / name
    low, high = (f"{r:g}" for r in RATES)
    side_by_side([f"{prefix}-ours-{low}.npy", f"{prefix}-yt.npy", f"{prefix}-vtk.npy",
                  f"{prefix}-vtk-amr.npy", f"{prefix}-uniform-{low}.npy"],
                 Path(args.images) / f"peers-{name}.png", args.size)
    row["agreement"] = {
        "yt": image_agreement(f"{prefix}-ours-{high}.npy", f"{prefix}-yt.npy"),
        # VTK samples every half finest cell: ours at the same density (rate 2).
        "vtk": image_agreement(f"{prefix}-ours-{low}.npy", f"{prefix}-vtk.npy"),
        "vtk-amr": image_agreement(f"{prefix}-ours-{low}.npy", f"{prefix}-vtk-amr.npy"),
        **{f"uniform-{r}": image_agreement(f"{prefix}-ours-{r}.npy", f"{prefix}-uniform-{r}.npy")
           for r in (low, high)}}
    return row


def machine() -> str:
    """benchdoc's machine line with the OpenCL device and the pyopencl and yt versions."""
    versions = []
    for module, attribute in (("pyopencl", "VERSION_TEXT"), ("yt", "__version__")):
        try:
            versions.append(f"{module} {getattr(__import__(module), attribute)}")
        except ImportError:
            versions.append(f"{module} not installed")
    try:
        from importlib.metadata import version

        versions.append(f"vtk {version('vtk')}")
    except ImportError:
        versions.append("vtk not installed")
    return f"{benchdoc.machine(opencl=True)}, {', '.join(versions)} (yt: OpenMP, all cores)"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--datasets", default="amrex,athena,gerris,enzo,shell256,big")
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--docs", default=str(benchdoc.DOCS),
                   help=f"markdown file whose section '## {SECTION}' is replaced")
    p.add_argument("--images", default=str(ROOT / "docs" / "images"))
    p.add_argument("--max-voxels", type=int, default=MAX_VOXELS)
    p.add_argument("--alpha-scale", type=float, default=ALPHA_SCALE,
                   help="scale of the default preset's opacity ramp (1: the preset itself)")
    p.add_argument("--no-yt", action="store_true", help="skip yt (exabricks and the ceiling only)")
    p.add_argument("--yt-max-cells", type=int, default=YT_MAX_CELLS,
                   help="skip yt on datasets with more leaf cells than this")
    p.add_argument("--no-vtk", action="store_true",
                   help="skip VTK (resample + fixed-point ray caster, vtkAMRVolumeMapper)")
    p.add_argument("--vtk-threads", type=int, default=os.cpu_count() or 1,
                   help="threads of VTK's fixed-point ray caster and of Mesa's llvmpipe "
                        "(LP_NUM_THREADS); default: all cores")
    p.add_argument("--json", help="also write the raw results here")
    p.add_argument("--worker", nargs=3, metavar=("KIND", "SPEC", "RESULT"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        kind, spec_path, result_path = args.worker
        result = WORKERS[kind](json.loads(Path(spec_path).read_text()))
        Path(result_path).write_text(json.dumps(result))
        return 0
    names = [n.strip() for n in args.datasets.split(",") if n.strip()]
    unknown = [n for n in names if n not in DATASETS]
    if unknown:
        p.error(f"unknown dataset(s) {', '.join(unknown)} (known: {', '.join(DATASETS)})")
    if args.size < 2:
        p.error("--size must be at least 2")
    if args.runs < 1:
        p.error("--runs must be at least 1")
    if args.vtk_threads < 1:
        p.error("--vtk-threads must be at least 1")
    machine_line = machine()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-peers-") as tmp:
        for name in names:
            print(f"{name} ...", file=sys.stderr, flush=True)
            rows.append(bench_dataset(name, args, Path(tmp)))
    lines = report(rows, machine_line, args)
    print("\n".join(lines))
    benchdoc.replace_section(SECTION, "\n".join(lines), Path(args.docs))
    if args.json:
        Path(args.json).write_text(json.dumps({"machine": machine_line, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
