"""Write AMReX (BoxLib) plotfiles: `Header`, `Level_N/Cell_H`, `Level_N/Cell_D_00000`.

Used by the reader tests (tests/readers/test_readers_yt.py: small plotfiles of random data in
every real format and VisMF version) and by benchmarks/make_big.py (a >= 20 M-leaf
plotfile of the benchmark field).  The layout is what AMReX's WriteMultiLevelPlotfile
and VisMF::Write produce (compare tests/data/amrex-advection3d/plt00020): one
`Cell_D_00000` per level holding every FAB in box order, each a text header line
(VisMF version 1) then its components one after the other, x fastest.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

# Real descriptors of IEEE 64- and 32-bit reals per byte order (FPC::Ieee*RealDescriptor).
_RD64 = {"<": "((8, (64 11 52 0 1 12 0 1023)),(8, (8 7 6 5 4 3 2 1)))",
         ">": "((8, (64 11 52 0 1 12 0 1023)),(8, (1 2 3 4 5 6 7 8)))"}
_RD32 = {"<": "((8, (32 8 23 0 1 9 0 127)),(4, (4 3 2 1)))",
         ">": "((8, (32 8 23 0 1 9 0 127)),(4, (1 2 3 4)))"}


def _box(lo, hi) -> str:
    return f"(({lo[0]},{lo[1]},{lo[2]}) ({hi[0]},{hi[1]},{hi[2]}) (0,0,0))"


def write_plotfile(root: Path, boxes, ratios: Sequence[int], names: Sequence[str],
                   data: Callable[[int, np.ndarray, np.ndarray], np.ndarray], *,
                   real="<f8", ngrow=0, vismf=1, base=8, prob_lo=(0.0, 0.0, 0.0),
                   prob_hi=(1.0, 1.0, 1.0), keep=True):
    """Write a 3D cell-centred plotfile directory `root`; returns {level: [(lo, hi, values)]}.

    boxes: per level a list of (lo, hi) inclusive index boxes; level 0 has domain base^3
    and level L the domain refined by ratios[:L].  data(L, glo, ghi) gives the values of
    the box grown by `ngrow` ghost cells, (len(names), nz, ny, nx) array (x fastest in
    the file), in data units; it is called once per box, level by level in box order.
    The returned values are those boxes without ghost cells (None unless `keep`).
    """
    root = Path(root)
    dt = np.dtype(real)
    rd = (_RD64 if dt.itemsize == 8 else _RD32)[dt.byteorder if dt.byteorder in "<>" else "<"]
    root.mkdir()
    finest = len(boxes) - 1
    n = [base * int(np.prod(ratios[:L])) for L in range(finest + 1)]
    dx = [(np.array(prob_hi) - prob_lo) / n[L] for L in range(finest + 1)]
    lines = ["HyperCLaw-V1.1", str(len(names)), *names, "3", "1.5", str(finest),
             " ".join(map(str, prob_lo)), " ".join(map(str, prob_hi)),
             " ".join(map(str, ratios)),
             " ".join(_box((0, 0, 0), (m - 1,) * 3) for m in n),
             " ".join("0" for _ in n), *(" ".join(repr(float(v)) for v in d) for d in dx), "0", "0"]
    written = {}
    for L, level_boxes in enumerate(boxes):
        lines += [f"{L} {len(level_boxes)} 1.5", "0"]
        for lo, hi in level_boxes:
            for a in range(3):
                lines.append(f"{float(prob_lo[a] + lo[a] * dx[L][a])!r} "
                             f"{float(prob_lo[a] + (hi[a] + 1) * dx[L][a])!r}")
        lines.append(f"Level_{L}/Cell")
        d = root / f"Level_{L}"
        d.mkdir()
        fods, written[L], stats = [], [], []
        with open(d / "Cell_D_00000", "wb") as f:
            for lo, hi in level_boxes:
                glo, ghi = np.array(lo) - ngrow, np.array(hi) + ngrow
                values = np.asarray(data(L, glo, ghi))
                assert values.shape == (len(names), *(ghi - glo + 1)[::-1]), values.shape
                fods.append(f.tell())
                if vismf == 1:
                    f.write(f"FAB {rd}{_box(glo, ghi)} {len(names)}\n".encode())
                f.write(values.astype(dt).tobytes())
                g = slice(ngrow, -ngrow or None)
                inner = values[:, g, g, g]
                stats.append((inner.min(axis=(1, 2, 3)), inner.max(axis=(1, 2, 3))))
                written[L].append((np.array(lo), np.array(hi), inner if keep else None))
        cell_h = [str(vismf), "1", str(len(names)), str(ngrow), f"({len(level_boxes)} 0",
                  *(_box(lo, hi) for lo, hi in level_boxes), ")", str(len(level_boxes)),
                  *(f"FabOnDisk: Cell_D_00000 {o}" for o in fods), ""]
        if vismf in (1, 3):
            for s in (0, 1):  # per-box minima, then maxima, of each component
                cell_h.append(f"{len(level_boxes)},{len(names)}")
                cell_h += ["".join(f"{v:.17e}," for v in st[s]) for st in stats]
                cell_h.append("")
        if vismf != 1:
            cell_h.append(rd)
        (d / "Cell_H").write_text("\n".join(cell_h) + "\n")
    (root / "Header").write_text("\n".join(lines) + "\n")
    return written
