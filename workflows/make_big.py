"""Write a smooth multi-scale raw volume for scale tests and print the command that ingests it.

    .venv/bin/python workflows/make_big.py [--size 512] [--out bench-data/big512.raw] [--check]

The field is a sum of separable terms (Gaussian blobs of widths from 1/4 to 1/100
of the domain, and a few sinusoids): one big smooth blob where 2x2x2 groups merge
to coarse cells, medium blobs, and small sharp features that stay at the finest
level.  Each term is a product g_x(x) g_y(y) g_z(z), so a z-slab of the volume is
one matrix product (slab terms x plane terms) -- a 512^3 volume takes seconds.
Values are float32, x fastest, little-endian, origin 0, spacing 1.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# Threshold and coarsest level for the printed ingest command: with them the 512^3
# volume becomes 23.6 M cells over 6 levels (checked with --check; numbers in
# docs/benchmarks.md).
THRESHOLD = 0.005
MAX_LEVEL = 5


def terms(seed: int) -> list[tuple[float, tuple, tuple]]:
    """(amplitude, (kind, params) per axis) of every separable term, in unit coordinates."""
    rng = np.random.default_rng(seed)
    out = []
    # Gaussian blobs at decreasing scales: (count, sigma, amplitude)
    for count, sigma, amp in ((1, 0.25, 1.0), (4, 0.08, 0.5), (12, 0.03, 0.3), (40, 0.01, 0.2)):
        for _ in range(count):
            centre = rng.uniform(0.15, 0.85, 3)
            s = sigma * rng.uniform(0.7, 1.3)
            out.append((amp * rng.uniform(0.5, 1.0), tuple(("gauss", c, s) for c in centre)))
    # Low-amplitude waves, so that no large region is exactly constant.
    for k in (2, 5):
        phase = rng.uniform(0, 2 * np.pi, 3)
        out.append((0.02, tuple(("sin", k, p) for p in phase)))
    return out


def axis_values(spec: tuple, n: int) -> np.ndarray:
    """One factor of a term on the n voxel centres of an axis, float64 (n,)."""
    x = (np.arange(n) + 0.5) / n
    kind, a, b = spec
    if kind == "gauss":
        return np.exp(-0.5 * ((x - a) / b) ** 2)
    return 0.5 + 0.5 * np.sin(2 * np.pi * a * x + b)


def generate(path: Path, size: int, seed: int, slab: int = 16) -> None:
    """Write the size^3 float32 volume to `path`, slab by slab along z."""
    spec = terms(seed)
    amp = np.array([a for a, _ in spec])
    gx = np.stack([axis_values(s[0], size) for _, s in spec])  # (T, X)
    gy = np.stack([axis_values(s[1], size) for _, s in spec])  # (T, Y)
    gz = np.stack([axis_values(s[2], size) for _, s in spec])  # (T, Z)
    plane = (gy[:, :, None] * gx[:, None, :]).reshape(len(spec), -1)  # (T, Y*X)
    weights = (amp[:, None] * gz).T  # (Z, T)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        for z0 in range(0, size, slab):
            block = (weights[z0:z0 + slab] @ plane).astype("<f4")
            block.tofile(f)
    tmp.replace(path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=512, help="voxels per axis (default 512)")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--out", type=Path, default=None, help="default bench-data/bigSIZE.raw")
    p.add_argument("--check", action="store_true",
                   help="also run the merge and print cells per level")
    args = p.parse_args(argv)
    out = args.out or ROOT / "bench-data" / f"big{args.size}.raw"
    t = time.perf_counter()
    generate(out, args.size, args.seed)
    print(f"wrote {out} ({args.size}^3 float32) in {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
    n = args.size
    command = (f"exabricks ingest --format raw --dims {n} {n} {n} --dtype float32 "
               f"--max-level {MAX_LEVEL} --threshold {THRESHOLD} {out} -o {out.with_suffix('.npz')}")
    if args.check:
        from exabricks.stages.ingest import amr_from_uniform

        volume = np.fromfile(out, dtype="<f4").reshape(n, n, n)
        t = time.perf_counter()
        _, level, _ = amr_from_uniform(volume, max_level=MAX_LEVEL, threshold=THRESHOLD)
        per_level = np.bincount(level)
        print(f"merge: {level.size:,} cells in {time.perf_counter() - t:.1f} s; per level "
              + ", ".join(f"{l}: {c:,}" for l, c in enumerate(per_level)), file=sys.stderr)
    print(command, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
