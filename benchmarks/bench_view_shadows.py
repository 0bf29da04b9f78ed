"""The viewer under the shadow integrator against the headlight: how long a camera
change takes to its first frame and to the converged one (docs/view.md, "Lights";
issue 62).

    .venv/bin/python -m benchmarks.bench_view_shadows [--runs N] [--only KEY] [--write-docs]

Each shared dataset is opened as `exabricks view SOURCE` opens it, with the field
of benchdoc, a 512² frame at 2 samples per pixel, under the headlight and under
`--integrator shadow`, one session each. The page's part is played as the page
plays it: the key light of the first frame becomes the scene's own (session.key_light),
so that the light stays fixed as the camera orbits. Each run orbits the camera by
10 degrees and draws the stages exabricks.viewer.session.Session draws for it
(coarse, full, converged), timed from the moment the new scene arrives. Median and
min-max over the runs, after one warm-up orbit (the first light's volume is built
there); "ratio" is shadow / headlight of the medians.
"""

from __future__ import annotations

import argparse
import time

from benchmarks import benchdoc
from benchmarks.bench_view import orbit

TITLE = "Viewer: shadows against the headlight"
STAGES = ("coarse", "converged")


def measure(dataset, integrator: str, runs: int) -> dict[str, list[float]]:
    import exabricks as eb
    from exabricks.viewer.session import Session, key_light

    ds = eb.open(dataset.path, **({"format": "yt"} if dataset.key == "enzo" else {}))
    session = Session(ds, options={"field": dataset.field, "size": (512, 512), "spp": 2,
                                   "integrator": integrator})
    doc = session.doc
    times = {stage: [] for stage in STAGES}
    for run in range(runs + 1):
        doc = orbit(doc, 10)
        started = time.perf_counter()
        scene = session.check(doc)
        for stage, staged in session.stages(scene):
            session.draw(stage, staged)
            if run and stage in times:
                times[stage].append(time.perf_counter() - started)
        key = key_light(scene)
        if key is not None:  # the page takes it as the scene's own
            doc["lighting"] = {**doc["lighting"], "light": {"direction": key}}
    return times


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=5)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_view_shadows --runs {args.runs}`.", "",
            "| dataset | " + " | ".join(f"{s}: headlight ms | {s}: shadow ms | {s}: ratio" for s in STAGES) + " |",
            "|---|" + "---:|---:|---:|" * len(STAGES)]
    for key in benchdoc.chosen(args.only, ["gerris", "amrex", "athena", "enzo"]):
        got = {i: measure(sets[key], i, args.runs) for i in ("headlight", "shadow")}
        cells = []
        for stage in STAGES:
            h, s = (benchdoc.median_spread(got[i][stage])[0] for i in ("headlight", "shadow"))
            cells += [benchdoc.fmt_spread([1e3 * t for t in got["headlight"][stage]], unit="", digits=0),
                      benchdoc.fmt_spread([1e3 * t for t in got["shadow"][stage]], unit="", digits=0),
                      f"{s / h:.2f}"]
        print(key, cells, flush=True)
        body.append(f"| {sets[key].name} | " + " | ".join(cells) + " |")
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
