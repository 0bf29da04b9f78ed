"""The report of benchmarks/bench_peers.py: from the rows its driver collects (one per
dataset, each worker's results), the figures against the issues' targets (TARGETS) and
their verdicts, where the time goes, the tables (exabricks vs yt, vs VTK, regions vs
cell location, vs the uniform-grid ceiling) and the notes on how each peer was matched,
as the markdown of the section SECTION of docs/benchmarks.md."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.peers.common import MAX_OPACITY, OPACITY_UNIT_CELLS, RATE_KEYS, RATES, SEED
from benchmarks.peers.yt import YT_NBINS, YT_NUM_SAMPLES, YT_PAD

SECTION = "exabricks vs yt, cell location and the uniform-grid ceiling"
# The targets: yt / ours frame time at each tool's default sampling and with ours
# at RATES[-1]; cell location / regions kernel time; ours / uniform-grid samples per second.
# Issue 15's targets (issue 10's for cell location): yt's on the block-structured
# datasets, VTK's as VTK time / ours (its frame at half a finest cell, ours at rate 2).
TARGETS = {"yt_default": 6.0, "yt_equal": 2.5, "cell_location": 2.0, "ceiling": 0.8,
           "vtk_frame": 2.0, "vtk_first_image": 3.0,
           # issue 10's, on octree-like data
           "yt_default_octree": 3.0, "yt_equal_octree": 1.2}
BLOCK_STRUCTURED = ("amrex", "athena")
OCTREE_LIKE = ("gerris", "shell256")


def fmt_s(times) -> str:
    """'median (min-max)' of a list of seconds; '-' for none."""
    return benchdoc.fmt_spread(times, unit="") if times else "-"


def fmt_ms(times) -> str:
    return benchdoc.fmt_spread(1e3 * np.asarray(times), unit="", digits=0) if times else "-"


def fmt_agreement(m: dict | None) -> str:
    if not m:
        return "-"
    ssim = "-" if m["ssim"] is None else f"{m['ssim']:.3f}"
    return f"{m['psnr']:.1f} / {ssim}"


def _median(values) -> float:
    return benchdoc.median_spread(values)[0]


def _measured(r) -> bool:
    """Whether `r` has our frames (the prepare and exabricks workers both succeeded)."""
    o = r.get("ours", {})
    return bool(o) and "error" not in o and not r.get("error") and "error" not in r.get("prep", {})


def _span(values, digits: int = 1) -> str:
    """'lo-hi' of a list of figures, or one figure when both ends round alike."""
    lo, hi = (f"{v:.{digits}f}" for v in (min(values), max(values)))
    return lo if lo == hi else f"{lo}-{hi}"


def ceiling_ratios(rows) -> dict:
    """{(dataset, rate key): ours / uniform-grid samples per second (median kernel times)}."""
    out = {}
    for r in rows:
        u = r.get("uniform")
        if not _measured(r) or not u or not u.get("fits"):
            continue
        for rate in RATE_KEYS:
            a, b = r["ours"]["rates"][rate], u["rates"][rate]
            out[r["name"], rate] = ((a["samples"] / _median(a["kernel_s"]))
                                    / (b["samples"] / _median(b["kernel_s"])))
    return out


def yt_ratios(rows, rate: str) -> dict:
    """{dataset: median yt frame / median ours frame at `rate`} where yt ran."""
    return {r["name"]: _median(r["yt"]["frame_s"]) / _median(r["ours"]["rates"][rate]["frame_s"])
            for r in rows if _measured(r) and r.get("yt") and "error" not in r["yt"]}


def gaps(rows, machine_line: str) -> list[str]:
    """Where the time goes and what would close the gaps, with this run's figures."""
    measured = [r for r in rows if _measured(r)]
    if not measured:
        return []
    count = [r["prep"]["bricks_per_region_by_count"] for r in measured]
    volume = [r["prep"]["bricks_per_region_by_volume"] for r in measured]
    text = ("Where the time goes. Per sample ours evaluates the hat sums of every brick in its "
            f"region's list ({_span(count)} bricks per region by count, {_span(volume)} by "
            "volume on these datasets), then the same transfer function, opacity and "
            "compositing code as the uniform-grid marcher, which does one trilinear lookup "
            "per sample and no region walk.")
    if "pocl" in machine_line.lower():
        text += (" On PoCL ours reconstructs and shades the next eight samples of a ray at "
                 "once in vector registers (sample packets, kernels/packet.cl, spanning up to "
                 "three region visits), while the "
                 "marcher stays scalar (one sample at a time, as our GPU path), and yt's C ray "
                 "caster runs one OpenMP thread per core.")
    ceiling = ceiling_ratios(measured)
    if ceiling:
        (name, rate), worst = min(ceiling.items(), key=lambda kv: kv[1])
        prep = next(r["prep"] for r in measured if r["name"] == name)
        text += (f" Ours is furthest from the marcher on {name} at rate {float(rate):g} "
                 f"({worst:.2f} of its samples per second), with "
                 f"{prep['cells'] / prep['bricks']:.1f} cells per brick and "
                 f"{prep['regions'] / prep['cells']:.2f} regions per leaf cell: the smaller the "
                 "bricks and regions, the fewer samples each region visit (a heap step and a "
                 "box test) buys.")
    near = yt_ratios(measured, RATE_KEYS[-1])
    if near:
        name = min(near, key=near.get)
        text += (f" yt comes closest to ours on {name} ({near[name]:.1f}x our frame time at "
                 f"{RATES[-1]:g} samples per finest cell).")
    return [
        text,
        "",
        "What would close the gaps (these frames profiled: docs/benchmarks.md, \"Where "
        "bench_peers' frame goes (perf)\"; what bounds each missed target: \"What bounds the "
        "missed targets\"): with packets the reconstruction's gathers (one per corner, lane and "
        "listed brick) and the transfer function's are the largest parts, then the walk and the "
        "compositing; in a volume frame a packet of samples spans up to three region visits "
        "of its ray, with the union of their brick lists (7.3 of 8 lanes full on Gerris). On "
        "octree-like data the reconstruction from long lists and the region walk, which packets "
        "do not touch, weigh most, although `brick` now joins the small bricks the k-d "
        "partition leaves and packets pass over listed bricks that reach none of their lanes "
        "(docs/design.md \"Bricks\", \"Sample packets on CPU devices\"): a cheaper "
        "step from one region to the next would help there; packets of rays that share a walk "
        "would fill the lanes better on block-structured data. On a GPU the kernels run one "
        "ray per lane, one sample at a time.",
    ]


def _verdict(name: str, target: float, values: dict, unit: str) -> str:
    """One line of the targets summary: each figure, and where it falls short of `target`."""
    if not values:
        return f"- {name} (target {target:g}{unit}): not measured"
    shown = ", ".join(f"{k} {v:.2f}{unit}" for k, v in values.items())
    missed = {k: v for k, v in values.items() if v < target}
    if not missed:
        verdict = "met on every one"
    else:
        worst = min(missed.values())
        verdict = (f"missed on {', '.join(missed)} (worst {worst:.2f}{unit}, "
                   f"{target / worst:.1f}x short)")
    return f"- {name} (target {target:g}{unit}): {shown}; {verdict}"


def target_figures(rows) -> dict:
    """This run's figure for each of TARGETS: {target key: {label: figure}} (`targets`)."""
    low, high = RATE_KEYS
    cell = {}
    for r in rows:
        c = r.get("cell_location")
        if not _measured(r) or not c:
            continue
        for rate in RATE_KEYS:
            cell[f"{r['name']} rate {float(rate):g}"] = (
                _median(c["rates"][rate]["kernel_s"]) / _median(r["ours"]["rates"][rate]["kernel_s"]))
    block = lambda ratios: {k: v for k, v in ratios.items() if k in BLOCK_STRUCTURED}
    octree = lambda ratios: {k: v for k, v in ratios.items() if k in OCTREE_LIKE}
    vtk = vtk_ratios(rows)
    return {"yt_default": block(yt_ratios(rows, low)), "yt_equal": block(yt_ratios(rows, high)),
            "yt_default_octree": octree(yt_ratios(rows, low)),
            "yt_equal_octree": octree(yt_ratios(rows, high)),
            "vtk_frame": {k: v["frame"] for k, v in vtk.items() if "frame" in v},
            "vtk_first_image": {k: v["first_image"] for k, v in vtk.items() if "first_image" in v},
            "cell_location": cell,
            "ceiling": {f"{name} rate {float(rate):g}": v
                        for (name, rate), v in ceiling_ratios(rows).items()}}


def targets(rows) -> list[str]:
    """The issue's targets (TARGETS) against this run's figures, dataset by dataset."""
    figures = target_figures(rows)
    return [
        "Targets (from this run):",
        "",
        _verdict("yt / ours, each at its default sampling (block-structured datasets)",
                 TARGETS["yt_default"], figures["yt_default"], "x"),
        _verdict(f"yt / ours, ours at {RATES[-1]:g} samples per finest cell (block-structured)",
                 TARGETS["yt_equal"], figures["yt_equal"], "x"),
        _verdict("yt / ours, each at its default sampling (octree-like datasets)",
                 TARGETS["yt_default_octree"], figures["yt_default_octree"], "x"),
        _verdict(f"yt / ours, ours at {RATES[-1]:g} samples per finest cell (octree-like)",
                 TARGETS["yt_equal_octree"], figures["yt_equal_octree"], "x"),
        _verdict("VTK fixed-point frame / ours at rate 2", TARGETS["vtk_frame"],
                 figures["vtk_frame"], "x"),
        _verdict("VTK to the first image from the files / ours", TARGETS["vtk_first_image"],
                 figures["vtk_first_image"], "x"),
        _verdict("cell location / regions", TARGETS["cell_location"], figures["cell_location"], "x"),
        _verdict("ours / uniform-grid samples per second", TARGETS["ceiling"], figures["ceiling"], ""),
    ]


def _off_axis_stretch(camera_dict: dict, size: int) -> float:
    """Largest 1/cos(angle between a pixel's ray and the view axis) - 1 of a size^2 frame."""
    from exabricks.picture.camera import Camera

    camera = Camera.from_dict(camera_dict)
    _, forward, _, _ = camera.frame(size, size)
    _, directions = camera.rays(size, size)
    cosine = (directions @ np.asarray(forward, np.float64)) / (
        np.linalg.norm(directions, axis=-1) * np.linalg.norm(forward))
    return float((1.0 / cosine).max() - 1.0)


def unit_note(rows) -> str:
    """What the opacity unit is, in finest cells, dataset by dataset (from the rows)."""
    cells = {}
    for r in rows:
        prep = r.get("prep", {})
        if "unit_distance" in prep:
            cells.setdefault(f"{prep['unit_distance'] / prep['finest_cell_world']:g}", []).append(
                r["name"])
    return "; ".join(f"{n} finest cell{'s' if n != '1' else ''} of {', '.join(names)}"
                     for n, names in cells.items())


def ours_first_image_s(r) -> float:
    """Our time from the raw dataset to the first image: read + brick/regions/BVH build (the
    prepare worker, without saving) + OpenCL program + upload + the first frame at rate 2."""
    prep, o = r["prep"], r["ours"]
    return (prep["read_s"] + prep["build_s"] + o["kernel_build_s"] + o["upload_s"]
            + o["rates"][RATE_KEYS[0]]["first_frame_s"])


def vtk_ratios(rows) -> dict:
    """{dataset: {figure: VTK / ours}} where VTK ran: "frame" (median fixed-point frame /
    median ours frame at rate 2), "first_image" (VTK's reader + resample + first frame /
    ours_first_image_s), and "amr_frame", "amr_first_image" for vtkAMRVolumeMapper."""
    out = {}
    for r in rows:
        v = r.get("vtk")
        if not _measured(r) or not v or "error" in v:
            continue
        ours_frame, ours_first = _median(r["ours"]["rates"][RATE_KEYS[0]]["frame_s"]), \
            ours_first_image_s(r)
        figures = {}
        for prefix, part in (("", v.get("resample", {})), ("amr_", v.get("amr_mapper", {}))):
            if part.get("frame_s") and "error" not in part:
                figures[prefix + "frame"] = _median(part["frame_s"]) / ours_frame
                figures[prefix + "first_image"] = part["first_image_s"] / ours_first
        out[r["name"]] = figures
    return out


def _amr_grid(b: dict, finest) -> str:
    """'48x58x46 points, 2.2-2.8 finest cells apart' of vtkAMRVolumeMapper's grid."""
    if "grid_dims" not in b:
        return "-"
    cells = np.asarray(b["grid_spacing"], np.float64) / np.asarray(finest, np.float64)
    points = "x".join(map(str, b["grid_dims"]))
    return f"{points} points, {_span(cells.tolist())} finest cells apart"


def vtk_tables(rows, args) -> list[str]:
    """The two VTK tables of the report (benchmarks/peers/vtk.py, "How VTK is matched")."""
    low = RATE_KEYS[0]
    ratios = vtk_ratios(rows)
    lines = [
        "| dataset (field) | VTK reader | finest grid (resampled) | VTK read / resample s "
        "| VTK frame s (fixed point) | VTK first image s | ours frame s, rate "
        f"{float(low):g} | VTK / ours frame | ours first image s | VTK / ours first image "
        f"| peak RSS VTK MiB | image VTK vs ours (rate {float(low):g}): PSNR dB / SSIM |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    amr = [
        "| dataset | vtkAMRVolumeMapper grid (default 128^3 samples over the view frustum) "
        "| its level of resolution / finest level / mean level sampled | render mode "
        "| frame s | first image s "
        "| frame / ours | first image / ours "
        f"| image vs ours (rate {float(low):g}): PSNR dB / SSIM |",
        "|---|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        name = f"{r['name']} ({r.get('field', '-')})"
        v = r.get("vtk")
        failed = r.get("error") or r.get("prep", {}).get("error") or r.get("ours", {}).get("error")
        if failed or not v or "error" in v:
            why = failed or (v["error"] if v else "not run (--no-vtk)")
            lines.append(f"| {name} | {why} |" + " |" * 10)
            amr.append(f"| {r['name']} | {why} |" + " |" * 7)
            continue
        o, a, b = r["ours"], v.get("resample", {}), v.get("amr_mapper", {})
        f_low = o["rates"][low]["frame_s"]
        ours_first = ours_first_image_s(r)
        agreement = r.get("agreement", {})
        grid = "x".join(map(str, v["finest_dims"]))
        if "error" in a or not a.get("frame_s"):
            lines.append(f"| {name} | {v['reader']} | {a.get('error', 'no frames')} "
                         f"| {a.get('read_s', 0.0):.2f} / - | - | - | {fmt_s(f_low)} | - "
                         f"| {ours_first:.2f} | - | {v.get('peak_rss_mib', 0.0):.0f} | - |")
        else:
            lines.append(
                f"| {name} | {v['reader']} | {grid} | {a['read_s']:.2f} / {a['resample_s']:.2f} "
                f"| {fmt_s(a['frame_s'])} | {a['first_image_s']:.2f} | {fmt_s(f_low)} "
                f"| {ratios[r['name']]['frame']:.1f}x | {ours_first:.2f} "
                f"| {ratios[r['name']]['first_image']:.1f}x | {v.get('peak_rss_mib', 0.0):.0f} "
                f"| {fmt_agreement(agreement.get('vtk'))} |")
        if "error" in b or not b.get("frame_s"):
            amr.append(f"| {r['name']} | {b.get('error', 'no frames')} |" + " |" * 7)
        else:
            log = b.get("resampler", {})
            level, mean = log.get("requested_max_level"), log.get("average_level")
            levels = (f"{'-' if level is None else level} / {(v.get('levels') or 0) - 1} / "
                      f"{'-' if mean is None else f'{mean:.2f}'}")
            amr.append(
                f"| {r['name']} | {_amr_grid(b, v['finest_spacing'])} "
                f"| {levels} | {b.get('render_mode', '-')} "
                f"| {fmt_s(b['frame_s'])} | {b['first_image_s']:.2f} "
                f"| {ratios[r['name']]['amr_frame']:.1f}x "
                f"| {ratios[r['name']]['amr_first_image']:.1f}x "
                f"| {fmt_agreement(agreement.get('vtk-amr'))} |")
    ran = [r["vtk"] for r in rows if r.get("vtk") and "threads" in r["vtk"]]
    threads = ", ".join(map(str, sorted({v["threads"] for v in ran}))) or \
        str(getattr(args, "vtk_threads", "-"))
    renderer = ", ".join(sorted({v.get("gl_renderer", "?") for v in ran})) or "Mesa's llvmpipe"
    version = " " + "/".join(sorted({v["version"] for v in ran})) if ran else ""
    return [
        f"### exabricks vs VTK{version} (ParaView's CPU way; same field, camera, transfer "
        "function, image size)",
        "",
        "VTK renders offscreen through EGL (`VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`) on "
        f"{renderer}, `LP_NUM_THREADS={threads}`. *Resample + fixed point*: the dataset's VTK "
        "reader (every level, the field as cell data), `vtkResampleToImage` to the finest "
        "level's cell centres over the domain (once), `vtkFixedPointVolumeRayCastMapper` "
        f"({threads} threads, sample distance half a finest cell, i.e. ours at rate "
        f"{float(low):g}, no automatic adjustment, trilinear, no shading); first image = "
        "reader + resample + render window + first frame; frame = render + read-back, the "
        f"median of {args.runs} after that. *vtkAMRVolumeMapper*: on the reader's "
        "vtkOverlappingAMR, which it resamples itself to NumberOfSamples (default 128^3) "
        "points spread over the bounding box of the view frustum between the data's nearest "
        "and farthest depth, clipped to the domain (so fewer points land in the data), and "
        "renders with a vtkSmartVolumeMapper (render mode: what it chose here). Its grid is "
        "rebuilt outside it the same way to read the spacing; the level of resolution is what "
        "its vtkAMRResampleFilter printed (it still takes values from every level the reader "
        "loaded). Ours: first image = read + build (no .npz round trip) + OpenCL program + "
        f"upload + first frame; frames at rate {float(low):g}, shading none. Ratios above 1: "
        "VTK slower. Datasets without a VTK reader say so.",
        "",
        *lines,
        "",
        *amr,
    ]


def report(rows, machine_line: str, args) -> list[str]:
    """The markdown body of the docs section (benchmarks/bench_peers.py, "Results")."""
    low, high = RATE_KEYS
    rl, rh = float(low), float(high)
    command = (f".venv/bin/python -m benchmarks.bench_peers --datasets {args.datasets} "
               f"--size {args.size} --runs {args.runs}")
    if args.no_yt:
        command += " --no-yt"
    no_vtk = getattr(args, "no_vtk", False)
    if no_vtk:
        command += " --no-vtk"
    lines = [
        f"Command: `{command}`",
        "",
        f"- machine: {machine_line}",
        f"- frames: {args.size}x{args.size}, the median of {args.runs} frames after one warm-up "
        "(min-max in brackets); ours (both reconstructions) and the uniform grid take their "
        "frames in turn in one process, so machine load hits them alike",
        "",
        *targets(rows),
        "",
        "Where the time goes and what would close the gaps: see the notes after the tables.",
        "",
        "### exabricks vs yt (same field, camera, transfer function, image size)",
        "",
        "| dataset (field) | cells (levels) | offline: read + build s "
        "| ours: load / kernel build / upload s "
        f"| ours frame s, rate {rl:g} | ours frame s, rate {rh:g} "
        "| yt: import / load+index / scene s "
        f"| yt frame s ({YT_NUM_SAMPLES} samples/cell) | yt / ours (rate {rl:g}) "
        f"| yt / ours (rate {rh:g}) "
        f"| peak RSS ours / yt MiB | image yt vs ours (rate {rh:g}): PSNR dB / SSIM |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        prep, o = r.get("prep", {}), r.get("ours", {})
        failed = r.get("error") or prep.get("error") or o.get("error")
        if failed:
            lines.append(f"| {r['name']} | {failed} |" + " |" * 10)
            continue
        y = r.get("yt")
        f_low, f_high = o["rates"][low]["frame_s"], o["rates"][high]["frame_s"]
        if y and "error" not in y:
            yt_load = f"{y['import_s']:.2f} / {y['load_index_s']:.2f} / {y['setup_s']:.2f}"
            if y.get("convert_s") is not None:
                yt_load += f" (+ {y['convert_s']:.2f} our conversion)"
            yt_frame = fmt_s(y["frame_s"])
            ratio_low = f"{_median(y['frame_s']) / _median(f_low):.1f}x"
            ratio_high = f"{_median(y['frame_s']) / _median(f_high):.1f}x"
            rss = f"{o['peak_rss_mib']:.0f} / {y['peak_rss_mib']:.0f}"
        else:
            yt_load = yt_frame = y["error"] if y else "not run (--no-yt)"
            ratio_low = ratio_high = "-"
            rss = f"{o['peak_rss_mib']:.0f} / -"
        lines.append(
            f"| {r['name']} ({r['field']}) | {prep['cells']:,} ({prep['levels']}) "
            f"| {prep['read_s']:.2f} + {prep['build_s']:.2f} "
            f"| {o['load_s']:.2f} / {o['kernel_build_s']:.2f} / {o['upload_s']:.2f} "
            f"| {fmt_s(f_low)} | {fmt_s(f_high)} "
            f"| {yt_load} | {yt_frame} | {ratio_low} | {ratio_high} | {rss} "
            f"| {fmt_agreement(r.get('agreement', {}).get('yt'))} |")
    if not no_vtk:
        lines += ["", *vtk_tables(rows, args)]
    lines += [
        "",
        "### regions vs cell location (paper Table 3)",
        "",
        "Kernel ms per frame. Both use the regions to decide where to sample and take the "
        "same samples; *regions* reconstructs each sample from its region's brick list "
        "(paper §3.2), *cell location* finds the bricks by descending a binned-SAH tree "
        "over the brick supports (one brick per leaf) from the root for every sample "
        "(kernels/cell_location.cl, the paper's §6.4.2 comparison with the cell-location "
        "kernel of Wald et al. 2017). Speed-up: median cell location / median regions "
        "(min-max of the per-round ratios). Tree build: in a warm process (in brackets: the "
        "first build in the process, with numba loading its compiled code). Shading none, "
        "as in the rest of this section (the paper's Table 3 shades both with analytic "
        "gradients). On a CPU *regions* runs with sample packets (kernels/packet.cl) and "
        "cell location one sample at a time (a per-sample descent has no shared brick list "
        "to vectorise), so the speed-up there includes the packets' (docs/benchmarks.md, "
        "\"render (PoCL)\": 1.5-2.0x); on a GPU both run one sample at a time.",
        "",
        "| dataset | bricks | tree nodes / depth / build ms (first) | rate | samples | regions ms "
        "| cell location ms | speed-up | same frame (max abs diff) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        c = r.get("cell_location")
        if not _measured(r) or not c:
            continue
        tree = (f"{c['tree_nodes']:,} / {c['tree_depth']} / {1e3 * c['tree_build_s']:.1f} "
                f"({1e3 * c['tree_first_build_s']:.0f})")
        for rate in RATE_KEYS:
            a, b = r["ours"]["rates"][rate], c["rates"][rate]
            pairs = np.asarray(b["kernel_s"]) / np.asarray(a["kernel_s"])
            same = "yes" if b["samples"] == a["samples"] else f"no: {b['samples']:,} samples"
            lines.append(
                f"| {r['name']} | {r['prep']['bricks']:,} | {tree} | {float(rate):g} "
                f"| {a['samples']:,} | {fmt_ms(a['kernel_s'])} | {fmt_ms(b['kernel_s'])} "
                f"| {_median(b['kernel_s']) / _median(a['kernel_s']):.2f}x "
                f"({pairs.min():.2f}-{pairs.max():.2f}) "
                f"| {same} ({b['max_abs_vs_regions']:.1e}) |")
    lines += [
        "",
        "### exabricks vs the uniform-grid ceiling (median kernel time, samples counted alike)",
        "",
        "| dataset | finest grid | rate | ours samples | ours Msamples/s | uniform samples "
        "| uniform Msamples/s | ours / ceiling (samples/s) | kernel time uniform / ours "
        "| image uniform vs ours: PSNR dB / SSIM |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        u = r.get("uniform")
        if not _measured(r) or not u:
            continue
        grid = "x".join(map(str, u["dims"]))
        if not u.get("fits"):
            lines.append(f"| {r['name']} | {grid}: does not fit (> {args.max_voxels:,} voxels) |"
                         + " |" * 8)
            continue
        for rate in RATE_KEYS:
            a, b = r["ours"]["rates"][rate], u["rates"][rate]
            ka, kb = _median(a["kernel_s"]), _median(b["kernel_s"])
            rate_a, rate_b = a["samples"] / ka, b["samples"] / kb
            lines.append(
                f"| {r['name']} | {grid} | {float(rate):g} | {a['samples']:,} "
                f"| {rate_a / 1e6:.1f} | {b['samples']:,} | {rate_b / 1e6:.1f} "
                f"| {rate_a / rate_b:.2f} | {kb / ka:.2f} "
                f"| {fmt_agreement(r.get('agreement', {}).get(f'uniform-{float(rate):g}'))} |")
    preps = [r["prep"] for r in rows if "camera" in r.get("prep", {})]
    tf_names = sorted({f"`{p['transfer_function'].get('Name', 'custom')}`" for p in preps})
    skipped = [r["name"] for r in rows
               if r.get("yt") and str(r["yt"].get("error", "")).startswith("skipped")]
    lines += [
        "",
        f"Ours: pure emission-absorption (shading none), jitter on (seed {SEED}), early "
        f"termination at {MAX_OPACITY:g}, the preset {', '.join(tf_names) or '-'} "
        f"over the field's range with its opacity ramp scaled by {args.alpha_scale:g}, default "
        f"three-quarter camera, opacity unit = largest domain extent / {OPACITY_UNIT_CELLS} "
        f"({unit_note(rows) or '-'}). "
        "Offline: readers.read, then brick + regions + BVH in memory (the stages `exabricks "
        "ingest/brick/regions/bvh` run once per dataset). Ours load: the three .npz files "
        "(schema.load); kernel build: OpenCL context + program (pyopencl's binary cache warm "
        "after the first run); upload: `Renderer()` (buffers to the device). "
        "yt: `yt.load` + `ds.index`; "
        "scene = Scene, VolumeSource, transfer function, perspective camera and the AMRKDTree "
        "(vertex-centred bricks). Peak RSS of each tool in its own process (ours: before the "
        "uniform grid is resampled in the same process). yt is skipped on datasets with more "
        f"than --yt-max-cells ({args.yt_max_cells:,}) leaf cells"
        + (f" ({', '.join(skipped)} in this run). " if skipped else ". ")
        + "The uniform grid is resampled with exabricks' own basis "
        "reconstruction at every finest-cell centre (probe) and marched trilinearly with a "
        "constant step (kernels/uniform_grid.cl), with the same transfer function lookup, "
        "opacity correction and compositing code as ours. See benchmarks/peers/yt.py for "
        "how the yt camera and transfer function were matched and what still differs.",
        "",
        *gaps(rows, machine_line),
        "",
        "How yt was matched (details and the yt source lines in benchmarks/peers/yt.py):",
        "",
        "- Camera: `cam.focus = look_at`, `cam.set_position(position, north_vector=up)`, "
        "`lens_type=\"perspective\"`, `cam.width = [w0, w0, w2]` with "
        "`w0 = 2 w2 tan(fovy/2) (N-1)/N` (yt's outermost rays go through the image edges, "
        "ours through pixel centres; with this width every yt ray is exactly one of ours), "
        "w2 = 2 L (L below) so that yt's brick-ordering viewpoint lies behind the data; "
        "square images only. yt's image is ours transposed (`ours[row, col] = yt[col, row]`).",
        f"- Transfer function: ColorTransferFunction(grey_opacity=True, nbins={YT_NBINS}) over "
        f"the field range widened by {100 * YT_PAD:g} % (yt makes values on or outside its "
        "bounds transparent), "
        "`log_field = False`; tables filled at yt's nodes from our piecewise-linear function: "
        "colour = ours, alpha table = extinction `-ln(1 - alpha) L / unit_distance` per unit of "
        "yt's ray parameter (t in [0, 1] spans L = |camera - domain centre| + |domain width|/2 "
        "on the central ray); yt's step `1 - dt sigma` is the linearisation of our "
        "`(1 - alpha)^(dt / unit)`. Off-axis rays are up to 1/cos(angle) longer in t"
        + (f" (<= {100 * max(_off_axis_stretch(p['camera'], args.size) for p in preps):.1f} % "
           "in these frames)" if preps else "")
        + ", so slightly less opaque per world length in yt.",
        f"- Sampling: yt's default {YT_NUM_SAMPLES} samples per cell crossing (`num_samples`); "
        f"ours at the default {rl:g} and at {rh:g} samples per finest cell of each region.",
        "- Still different: yt walks each ray from the camera but composites each new sample "
        "*in front of* what it has accumulated, so occlusion is reversed relative to ours "
        "(two opaque slabs along the view: yt shows the far one); yt reconstructs trilinearly "
        "from vertex values averaged from cell values within each grid, we use the basis "
        "method; yt has no early ray termination. Images therefore agree in structure, "
        "not to the last bit (PSNR/SSIM column).",
        "",
    ]
    if not no_vtk:
        lines += [
            "How VTK was matched (benchmarks/peers/vtk.py, `worker_vtk`):",
            "",
            "- Camera: a vtkCamera with our position, focal point = look_at, view up = our up' "
            "(orthogonal to the view), view angle = fovy (vertical) and a clipping range "
            "around the data; VTK's perspective rays and ours both go through pixel centres, "
            "so the frames coincide; VTK's image rows start at the bottom and are flipped.",
            "- Transfer function: a vtkColorTransferFunction (RGB space) through our colour "
            "knots and a vtkPiecewiseFunction through our opacity knots, both clamped, "
            "`SetScalarOpacityUnitDistance(unit_distance)`: VTK corrects a step's opacity "
            "to `1 - (1 - alpha)^(dt / unit)` as we do.",
            f"- Sampling: a constant step of half a finest cell (ours at rate {rl:g}), "
            "no jitter; images compared with ours at that rate. The frame is VTK's 8-bit "
            "framebuffer (premultiplied over transparent black), read back as floats.",
            "- Still different: the resampled grid holds each finest cell's value at its "
            "centre (coarse cells repeated), trilinear between centres, so half a finest "
            "cell at each face of the domain is not rendered; we reconstruct with the basis "
            "method. The fixed-point caster composites in 15-bit fixed point with its own "
            "tables and stops rays at full opacity (ours at "
            f"{MAX_OPACITY:g}). vtkAMRVolumeMapper samples a much coarser grid (its table "
            "row) and renders it with its own sample distance.",
            "",
        ]
    for r in rows:
        png = Path(args.images) / f"peers-{r['name']}.png"
        if png.is_file():
            lines.append(f"![{r['name']}: ours | yt | VTK resample + fixed point | "
                         "vtkAMRVolumeMapper | uniform grid (grey: not run)]"
                         f"({os.path.relpath(png, Path(args.docs).parent)})")
    return lines
