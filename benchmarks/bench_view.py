"""The viewer's progressive frames (docs/view.md): how soon after an interaction the
page gets its first (coarse) frame, and when the frame is full size and converged.

    .venv/bin/python -m benchmarks.bench_view [--runs N] [--only KEY] [--write-docs]

Each shared dataset is opened as `exabricks view SOURCE` opens it (the structures
from the cache), with the field of benchdoc, a 512² frame at 2 samples per pixel
and one iso-surface at the middle of the field's range. Each run orbits the camera
by 10 degrees and draws the stages exabricks.viewer.session.Session draws for it:
the time of a stage counts the scene's checks, the frame and its PNG, from the
moment the new scene arrives (the moving stage uses level of detail 2, as the page
asks while a drag goes on). Median and min-max over the runs, after one warm-up.
"""

from __future__ import annotations

import argparse
import math
import time

from benchmarks import benchdoc

TITLE = "Viewer: progressive frames"


def orbit(doc: dict, degrees: float) -> dict:
    c = doc["camera"]
    (px, py, pz), (lx, _, lz) = c["position"], c["look_at"]
    a = math.radians(degrees)
    dx, dz = px - lx, pz - lz
    c["position"] = [lx + dx * math.cos(a) - dz * math.sin(a), py, lz + dx * math.sin(a) + dz * math.cos(a)]
    return doc


def measure(dataset, runs: int) -> dict[str, list[float]]:
    import exabricks as eb
    from exabricks.viewer.session import Session

    ds = eb.open(dataset.path, **({"format": "yt"} if dataset.key == "enzo" else {}))
    session = Session(ds, options={"field": dataset.field, "size": (512, 512), "spp": 2})
    field_range = session.info()["fields"][dataset.field]["range"]
    doc = session.doc
    doc["isosurfaces"] = [{"field": dataset.field, "value": sum(field_range) / 2, "color": [0.9, 0.9, 0.9],
                           "opacity": 1.0}]
    times = {"moving (coarse, lod 2)": [], "coarse": [], "full": [], "converged": []}
    for run in range(runs + 1):
        doc = orbit(doc, 10)
        started = time.perf_counter()
        for stage, scene in session.stages(session.check(doc), moving=True):
            session.draw(stage, scene)
        moving = time.perf_counter() - started
        started = time.perf_counter()
        marks = {}
        for stage, scene in session.stages(session.check(doc)):
            session.draw(stage, scene)
            marks[stage] = time.perf_counter() - started
        if run:
            times["moving (coarse, lod 2)"].append(moving)
            for stage, t in marks.items():
                times[stage].append(t)
    return times


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=5)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, ["gerris", "amrex", "athena", "enzo"])
    rows = []
    for key in keys:
        times = measure(sets[key], args.runs)
        rows.append((sets[key].name, times))
        print(key, {k: round(benchdoc.median_spread(v)[0] * 1e3, 1) for k, v in times.items()}, flush=True)
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_view --runs {args.runs}`.", "",
            *benchdoc.ms_table(rows)]
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
