"""OpenCL runtimes on a CPU: the default picture of each shared dataset on PoCL (the
system's driver) and on Intel's CPU runtime from PyPI (`pip install 'exabricks[cpu]'`),
with its vectorizer across work-items on and off (exabricks turns it off).

    .venv/bin/python -m benchmarks.bench_runtimes --intel-prefix ENV [--runs N] [--only KEY] [--write-docs]

ENV is a Python environment holding Intel's runtime (`python -m venv ENV &&
ENV/bin/pip install intel-opencl-rt intel-cmplr-lib-rt`); each runtime runs in a
child process of this Python with the loader pointed at it (OCL_ICD_VENDORS, as
exabricks.device.runtime does where no driver is installed). A frame is the
default render of the dataset at 512², its kernel time (the frame's `ms`) the
median and min-max of the runs after one warm-up frame, with the kernels built.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from benchmarks import benchdoc

TITLE = "OpenCL runtimes on a CPU"

CHILD = """
import json, sys
import exabricks as eb
path, field, fmt, runs = sys.argv[1], sys.argv[2] or None, sys.argv[3] or None, int(sys.argv[4])
renderer = eb.Renderer(eb.open(path, **({"format": fmt} if fmt else {})))
options = dict(size=(512, 512), **({"field": field} if field else {}))
image = renderer.render(**options)
times = [renderer.render(**options).metadata["settings"]["ms"] for _ in range(runs)]
print(json.dumps({"ms": times, "device": image.metadata["settings"]["device"]}))
"""


def runtimes(intel_prefix: Path) -> dict[str, dict]:
    """{label: environment changes} of the runtimes compared."""
    library = str(intel_prefix / "lib" / "libintelocl.so")
    # pyopencl's binary cache does not key on the vectorizer's variable: build afresh
    intel = {"OCL_ICD_VENDORS": library, "PYOPENCL_NO_CACHE": "1"}
    return {
        "PoCL (system driver)": {},
        "Intel CPU runtime, its vectorizer on": {**intel, "CL_CONFIG_CPU_VECTORIZER_MODE": "0"},
        "Intel CPU runtime (exabricks: vectorizer off)": {**intel, "CL_CONFIG_CPU_VECTORIZER_MODE": "1"},
    }


def measure(dataset, changes: dict, runs: int) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("OCL_ICD")}
    env.update(changes)
    fmt = "yt" if dataset.key == "enzo" else ""
    proc = subprocess.run([sys.executable, "-c", CHILD, str(dataset.path), dataset.field or "", fmt,
                           str(runs)], capture_output=True, text=True, env=env, cwd=benchdoc.ROOT)
    if proc.returncode != 0:
        raise SystemExit(proc.stderr)
    return json.loads(proc.stdout.splitlines()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=5)
    parser.add_argument("--intel-prefix", type=Path, required=True,
                        help="a Python environment holding intel-opencl-rt and intel-cmplr-lib-rt")
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, ["amrex", "athena", "gerris", "enzo"])
    compared = runtimes(args.intel_prefix)
    labels = list(compared)
    rows = []
    for key in keys:
        found = {label: measure(sets[key], changes, args.runs) for label, changes in compared.items()}
        rows.append((sets[key].name, found))
        print(key, {label: benchdoc.median_spread(r["ms"])[0] for label, r in found.items()}, flush=True)
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_runtimes --intel-prefix ENV "
            f"--runs {args.runs}`.", "",
            "| dataset | " + " | ".join(f"{label} (ms)" for label in labels) + " | Intel, vectorizer off / PoCL |",
            "|---|" + "---:|" * (len(labels) + 1)]
    for title, found in rows:
        cells = [benchdoc.fmt_spread(found[label]["ms"], unit="", digits=0) for label in labels]
        ratio = benchdoc.median_spread(found[labels[2]]["ms"])[0] / benchdoc.median_spread(found[labels[0]]["ms"])[0]
        body.append(f"| {title} | " + " | ".join(cells) + f" | {ratio:.2f} |")
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
