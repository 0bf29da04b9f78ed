"""Hypothesis fuzzers of the CLI contract (docs: DESIGN.md "Errors and exit status").

For any input every command either succeeds (exit 0) or prints exactly one
stderr line ``error: ...`` and exits 1 (2, click's usage error format, for bad
options); never a signal, a hang, a traceback or a RuntimeWarning; and a failed
run leaves neither its output nor a ``.eb-*.tmp`` temporary behind.

Every example runs the real CLI in a subprocess. Most fuzz a tiny hand-built
dataset (22 cells, three levels) so that an example costs well under a second;
the embedded Gerris plume gives a deep BVH for the link-field mutations and
the long render interrupted by the signal tests.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import AMREX, ATHENA, FUZZ_EXAMPLES, GERRIS, run_cli

from exabricks import schema

SUPPRESSED = [HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large]
TIMEOUT = 60
TMP_PATTERN = re.compile(r"^\.eb-.*\.tmp$")
KINDS = ("cells", "bricks", "regions", "bvh", "values")
HEADER = ("format", "kind", "version", "meta")

# ---------------------------------------------------------------------------
# running the CLI and checking the contract


def cli(*args, cwd=None, tmpdir=None, timeout=TIMEOUT):
    """`exabricks ARGS` in a subprocess (TMPDIR = `tmpdir`); a timeout fails as a hang."""
    env = {k: v for k, v in os.environ.items() if k not in ("EXABRICKS_DEBUG", "PYTHONWARNINGS")}
    if tmpdir is not None:
        env["TMPDIR"] = str(tmpdir)
    argv = [sys.executable, "-m", "exabricks.cli.main", *map(str, args)]
    try:
        return subprocess.run(argv, capture_output=True, text=True, errors="replace", env=env,
                              cwd=cwd, timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        pytest.fail(f"hang: no exit within {timeout} s: exabricks {shlex.join(map(str, args))}")


def temporaries(*dirs) -> list[str]:
    found = []
    for d in dirs:
        if d is not None and Path(d).is_dir():
            found += [str(Path(d, n)) for n in os.listdir(d) if TMP_PATTERN.match(n)]
    return found


def assert_contract(proc, *, outputs=(), dirs=(), note=""):
    """The CLI contract for one finished run. `outputs`: paths that did not exist
    before the run (must still not exist after a failure); `dirs`: directories
    where no `.eb-*.tmp` may remain."""
    rc, err = proc.returncode, proc.stderr
    what = (f"{note}\n$ exabricks {shlex.join(proc.args[3:])}\nexit status {rc}\n"
            f"stderr:\n{err}")
    assert rc >= 0, f"killed by signal {-rc} ({signal.Signals(-rc).name})\n{what}"
    assert rc in (0, 1, 2), what
    assert "Traceback" not in err, what
    assert "Warning" not in err, what
    lines = [line for line in err.splitlines() if line.strip()]
    if rc == 1:
        assert len(lines) == 1 and lines[0].startswith("error: "), what
    elif rc == 2:  # a usage error: one line too (exabricks.cli.main.usage_line)
        assert len(lines) == 1 and lines[0].startswith("error: "), what
    if rc != 0:
        left = [str(p) for p in outputs if os.path.lexists(p)]
        assert not left, f"a failed run left its output {left}\n{what}"
    left = temporaries(*dirs)
    assert not left, f"temporary files left behind: {left}\n{what}"


def sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def fresh_dir(parent) -> Path:
    return Path(tempfile.mkdtemp(dir=parent))


# ---------------------------------------------------------------------------
# the valid base files (built once per session)


def tiny_cells() -> schema.Cells:
    """8^3 lattice: seven level-2 octants, seven level-1 cells, eight level-0 cells."""
    lower, level = [], []
    for k in range(2):
        for j in range(2):
            for i in range(2):
                if (i, j, k) != (0, 0, 0):
                    lower += [(4 * i, 4 * j, 4 * k), (2 * i, 2 * j, 2 * k), (i, j, k)]
                    level += [2, 1, 0]
    lower.append((0, 0, 0))
    level.append(0)
    lower = np.array(lower, np.int32)
    level = np.array(level, np.int8)
    centre = lower + 0.5 * (1 << level.astype(np.int32))[:, None]
    values = (centre @ np.array([1.0, 0.5, 0.25]))[None].astype(np.float32)
    return schema.Cells(fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
                        meta=schema.make_meta(), lower_lattice=lower, level=level, values=values)


class Dataset:
    def __init__(self, directory: Path):
        self.dir = directory
        self.path = {k: directory / f"{k}.npz" for k in KINDS}
        self.points = directory / "points.npy"

    def arrays(self, kind) -> dict[str, np.ndarray]:
        with np.load(self.path[kind], allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def trio(self, **replace):
        return [replace.get(k, self.path[k]) for k in ("bricks", "regions", "bvh")]


def _build(directory: Path, leaf_size: int) -> Dataset:
    ds = Dataset(directory)
    p = ds.path
    run_cli("brick", p["cells"], "-o", p["bricks"], check=0)
    run_cli("regions", p["bricks"], "-o", p["regions"], check=0)
    run_cli("bvh", p["regions"], "-o", p["bvh"], "--leaf-size", leaf_size, check=0)
    run_cli("values", p["cells"], "--bricks", p["bricks"], "-o", p["values"], check=0)
    return ds


@pytest.fixture(scope="session")
def tiny(tmp_path_factory) -> Dataset:
    d = tmp_path_factory.mktemp("fuzz-tiny")
    schema.save(d / "cells.npz", tiny_cells())
    ds = _build(d, leaf_size=1)
    pts = np.array([[0.5, 0.5, 0.5], [3, 3, 3], [7.9, 0.1, 4], [-1, -1, -1], [4, 4, 4]], np.float64)
    np.save(ds.points, pts)
    return ds


@pytest.fixture(scope="session")
def gerris(tmp_path_factory) -> Dataset:
    d = tmp_path_factory.mktemp("fuzz-gerris")
    run_cli("ingest", GERRIS, "-o", d / "cells.npz", "--field", "T", check=0)
    ds = _build(d, leaf_size=4)
    np.save(ds.points, np.array([[64, 64, 64], [10, 20, 30], [200, 0, 0]], np.float64))
    return ds


# ---------------------------------------------------------------------------
# strategies for .npz mutations

EXTREMES = (0, -1, 2**31 - 1, -(2**31 - 1), 1e30, -1e30, float("nan"), float("inf"),
            float("-inf"), -2e9, 2e9, 1e-45)
DTYPES = (np.int8, np.uint8, np.int16, np.uint16, np.int32, np.uint32, np.int64, np.uint64,
          np.float16, np.float32, np.float64, np.bool_, np.complex64, np.dtype(">f4"),
          np.dtype(">i4"))
DEEP = 100_000


def cast(value, dtype):
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        return np.array(value).astype(dtype)


def deep_json(inner="") -> str:
    return "[" * DEEP + inner + "]" * DEEP


META_TEXTS = (
    deep_json(), '{"fields": ["v"], "x": ' + deep_json() + "}", '{"fields": ' + deep_json() + "}",
    "null", "[]", '"meta"', "3", "{}", '{"fields": "v"}', '{"fields": [1]}', '{"fields": ["v", "v"]}',
    '{"fields": []}', '{"fields": null}', "{", "", "NaN", '{"fields": ["v"], "consistency": "x"}',
    '{"fields": ["v"], "consistency": {"n_bricks": -1, "n_regions": 1e400}}',
    '{"fields": ["v"], "consistency": {"n_bricks": "7", "n_regions": null}}',
    '{"fields": ["' + "v" * 100_000 + '"]}', '{"fields": ["v"], "inputs": 5}',
    '{"fields": ["v"], "statistics": {"n_regions": -5}, "parameters": []}',
)
HEADER_VALUES = (
    "exabricks", "cells", "bricks", "regions", "bvh", "", "x" * 1000, "\x00", "bvh\n",
    np.array(1, np.int32), np.array(-1, np.int32), np.array(0, np.int32),
    np.array(2**31 - 1, np.int64), np.array(2**63 - 1, np.uint64), np.array(1.0), np.array(1.5),
    np.array(float("nan")), np.array(["cells", "bvh"]), np.array([1], np.int32),
    np.array(b"exabricks"), np.array(b"cells"), np.zeros((2, 2)), np.array(True),
    np.array("1"), np.zeros(0, np.int32), np.array([[1]], np.int32), np.array(1, np.int8),
)
META_VALUES = (None, -1, 0, 2**63, -(2**63) - 1, 1e308, "x", [], {}, [1, 2], {"n_bricks": 0},
               True, 1.5)


def header_value(data, key, arrays):
    choice = data.draw(st.sampled_from(("value", "meta_text", "meta_edit")), label=f"{key} how")
    if choice == "meta_text" or (choice == "meta_edit" and "meta" not in arrays):
        return np.array(data.draw(st.sampled_from(META_TEXTS), label="meta text"))
    if choice == "meta_edit":  # a valid meta with one key changed
        meta = json.loads(str(arrays["meta"]))
        paths = [(k,) for k in meta] + [(k, s) for k, v in meta.items() if isinstance(v, dict)
                                         for s in v]
        path = data.draw(st.sampled_from(paths), label="meta key")
        node = meta
        for p in path[:-1]:
            node = node[p]
        if data.draw(st.booleans(), label="delete key"):
            del node[path[-1]]
        else:
            node[path[-1]] = data.draw(st.sampled_from(META_VALUES), label="meta value")
        return np.array(json.dumps(meta))
    value = data.draw(st.sampled_from(HEADER_VALUES), label=f"{key} value")
    return value if isinstance(value, np.ndarray) else np.array(value)


def mutate_arrays(data, arrays: dict) -> tuple[dict, str]:
    """One structural mutation of the member arrays of an .npz; returns (arrays, description)."""
    arrays = dict(arrays)
    name = data.draw(st.sampled_from(sorted(arrays)), label="member")
    a = arrays[name]
    ops = ["delete", "header"] if name in HEADER else ["extreme", "dtype", "shape", "delete"]
    op = data.draw(st.sampled_from(ops), label="op")
    if op == "delete":
        del arrays[name]
        return arrays, f"deleted {name}"
    if op == "header":
        arrays[name] = header_value(data, name, arrays)
        return arrays, f"{name} = {str(arrays[name])[:80]!r} ({arrays[name].dtype})"
    if op == "extreme":
        a = a.copy()
        if a.size == 0:
            return arrays, f"{name} empty, unchanged"
        flat = a.reshape(-1)
        n = data.draw(st.integers(1, min(4, flat.size)), label="how many")
        idx = data.draw(st.lists(st.integers(0, flat.size - 1), min_size=n, max_size=n), label="at")
        vals = data.draw(st.lists(st.sampled_from(EXTREMES), min_size=n, max_size=n), label="vals")
        for i, v in zip(idx, vals):
            flat[i] = cast(v, a.dtype)
        arrays[name] = a
        return arrays, f"{name}[{idx}] = {vals}"
    if op == "dtype":
        dtype = data.draw(st.sampled_from(DTYPES), label="dtype")
        arrays[name] = cast(a, dtype)
        return arrays, f"{name}.astype({np.dtype(dtype)})"
    shape_ops = ["ravel", "add_axis", "empty", "scalar"]
    if a.ndim >= 1 and a.shape[0] > 0:
        shape_ops += ["drop_row", "dup_row"]
    if a.ndim >= 2:
        shape_ops += ["transpose"]
    sop = data.draw(st.sampled_from(shape_ops), label="shape op")
    if sop in ("drop_row", "dup_row"):
        i = data.draw(st.integers(0, a.shape[0] - 1), label="row")
        a = np.delete(a, i, axis=0) if sop == "drop_row" else np.insert(a, i, a[i], axis=0)
    elif sop == "transpose":
        a = np.ascontiguousarray(a.T)
    elif sop == "ravel":
        a = a.reshape(-1)
    elif sop == "add_axis":
        a = a[None] if data.draw(st.booleans(), label="front") else a[..., None]
    elif sop == "empty":
        a = a[:0] if a.ndim else a.reshape(1)[:0]
    else:
        a = a.reshape(-1)[:1].reshape(()) if a.size else np.array(0, a.dtype)
    arrays[name] = a
    return arrays, f"{name} {sop} -> shape {a.shape}"


def write_npz(path, arrays, compressed=False):
    with open(path, "wb") as f:
        (np.savez_compressed if compressed else np.savez)(f, **arrays)


def consumer_args(ds: Dataset, kind: str, path: Path, command: str, out_dir: Path):
    """(args, output) of a command that reads `path` in place of `ds`'s file of `kind`."""
    if command == "info":
        return ["info", path, "--json"], None
    if command in ("brick", "regions", "bvh"):
        out = out_dir / "out.npz"
        return [command, path, "-o", out], out
    trio = ds.trio(**{kind: path}) + (["--values", path] if kind == "values" else [])
    if command == "render":
        out = out_dir / "out.exr"
        return ["render", *trio, "--size", 16, 16, "-o", out], out
    out = out_dir / "out.npy"
    return ["probe", *trio, "--points", ds.points, "-o", out], out


CONSUMERS = {
    "cells": ("brick",),
    "bricks": ("regions", "render", "probe"),
    "regions": ("bvh", "render", "probe"),
    "bvh": ("render", "probe"),
    "values": ("render", "probe"),
}


def run_consumers(ds, kind, path, command, work, note):
    for cmd in ("info", command):
        args, out = consumer_args(ds, kind, path, cmd, work)
        proc = cli(*args, cwd=work, tmpdir=work)
        assert_contract(proc, outputs=[out] if out else [], dirs=[work], note=note)


# ---------------------------------------------------------------------------
# 1. mutated member arrays and headers of valid intermediate files


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_mutated_arrays(tiny, tmp_path, data):
    kind = data.draw(st.sampled_from(KINDS), label="kind")
    arrays, what = mutate_arrays(data, tiny.arrays(kind))
    compressed = data.draw(st.booleans(), label="compressed")
    command = data.draw(st.sampled_from(CONSUMERS[kind]), label="command")
    work = fresh_dir(tmp_path)
    path = work / f"mutated-{kind}.npz"
    write_npz(path, arrays, compressed)
    run_consumers(tiny, kind, path, command, work, f"{kind} file: {what} (compressed={compressed})")


# The links between and inside the files: what the kernels follow.
LINK_FIELDS = {
    "bvh": ("first", "count", "region_index", "finest_level", "lower_lattice", "upper_lattice",
            "value_range"),
    "regions": ("brick_start", "brick_ids", "finest_level", "lower_lattice", "upper_lattice",
                "value_range"),
    "bricks": ("dims", "offset", "level", "lower_lattice"),
}


def link_value(data, name, a, i):
    """A value for element `i` of link array `name` (shape of `a`) aimed at its meaning."""
    n = a.shape[0]
    common = [-1, 0, 1, n - 1, n, n + 1, 2**31 - 1, -(2**31), 2**30]
    if name == "first":
        choices = [i, 0, max(i - 1, 0), max(i - 2, 0), i + 1, n - 1, n - 2] + common
    elif name == "count":
        choices = [0, 1, -1, -5, 2**31 - 1, 1000, n] + common
    elif name in ("finest_level",) or name == "level":
        choices = [-1, 0, 1, 2, 3, 15, 30, 31, 32, 63, 64, 127, -128]
    elif name in ("lower_lattice", "upper_lattice"):
        choices = [float("nan"), float("inf"), float("-inf"), 1e30, -1e30, 1e-45, -0.5, 0.0,
                   2.0**24 + 1, -2.0**31, 2.0**31, 1e38]
    elif name == "value_range":
        choices = [float("nan"), float("inf"), float("-inf"), 1e30, -1e30, 1e-45, 0.0]
    else:
        choices = common + [2**40, -(2**40)]
    return data.draw(st.sampled_from(choices), label=f"{name}[{i}] value")


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_link_fields(tiny, gerris, tmp_path, data):
    ds = data.draw(st.sampled_from((tiny, tiny, tiny, gerris)), label="dataset")
    kind = data.draw(st.sampled_from(sorted(LINK_FIELDS)), label="kind")
    arrays = ds.arrays(kind)
    edits = []
    for _ in range(data.draw(st.integers(1, 3), label="edits")):
        name = data.draw(st.sampled_from(LINK_FIELDS[kind]), label="array")
        a = arrays[name] = arrays[name].copy()
        if name == "first" and data.draw(st.booleans(), label="inner node"):
            inner = np.flatnonzero(arrays["count"] == 0)
            i = int(data.draw(st.sampled_from(inner.tolist() or [0]), label="node"))
        elif name == "count" and data.draw(st.booleans(), label="leaf node"):
            leaves = np.flatnonzero(arrays["count"] > 0)
            i = int(data.draw(st.sampled_from(leaves.tolist() or [0]), label="node"))
        else:
            i = data.draw(st.integers(0, max(a.shape[0] - 1, 0)), label="row")
        if a.shape[0] == 0:
            continue
        v = link_value(data, name, a, i)
        row = a[i].reshape(-1)
        j = data.draw(st.integers(-1, row.size - 1), label="column (-1: all)")
        if a.ndim == 1 or j < 0:
            a[i] = cast(v, a.dtype)
        else:
            a.reshape(a.shape[0], -1)[i, j] = cast(v, a.dtype)
        edits.append(f"{name}[{i}{'' if a.ndim == 1 or j < 0 else f', {j}'}] = {v}")
    work = fresh_dir(tmp_path)
    path = work / f"linked-{kind}.npz"
    write_npz(path, arrays)
    command = data.draw(st.sampled_from(("render", "probe")), label="command")
    args, out = consumer_args(ds, kind, path, command, work)
    proc = cli(*args, cwd=work, tmpdir=work)
    assert_contract(proc, outputs=[out], dirs=[work],
                    note=f"{ds.dir.name} {kind} file: {'; '.join(edits)}")


# ---------------------------------------------------------------------------
# 2. byte-level mutations of a valid .npz


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_mutated_bytes(tiny, tmp_path, data):
    kind = data.draw(st.sampled_from(KINDS), label="kind")
    work = fresh_dir(tmp_path)
    src = work / "src.npz"
    write_npz(src, tiny.arrays(kind), compressed=data.draw(st.booleans(), label="compressed"))
    blob = bytearray(src.read_bytes())
    edits = []
    for _ in range(data.draw(st.integers(1, 4), label="edits")):
        op = data.draw(st.sampled_from(("flip", "overwrite", "truncate", "append", "insert",
                                        "zero")), label="op")
        pos = data.draw(st.integers(0, max(len(blob) - 1, 0)), label="pos")
        if op == "flip" and blob:
            bit = data.draw(st.integers(0, 7), label="bit")
            blob[pos] ^= 1 << bit
        elif op == "overwrite":
            new = data.draw(st.binary(min_size=1, max_size=16), label="bytes")
            blob[pos:pos + len(new)] = new
        elif op == "truncate":
            del blob[pos:]
        elif op == "append":
            blob += data.draw(st.binary(min_size=1, max_size=64), label="garbage")
        elif op == "insert":
            blob[pos:pos] = data.draw(st.binary(min_size=1, max_size=16), label="bytes")
        else:
            blob[pos:pos + data.draw(st.integers(1, 64), label="len")] = b""
        edits.append(f"{op}@{pos}")
    path = work / f"bytes-{kind}.npz"
    path.write_bytes(bytes(blob))
    command = data.draw(st.sampled_from(CONSUMERS[kind]), label="command")
    run_consumers(tiny, kind, path, command, work, f"{kind} file bytes: {', '.join(edits)}")


# ---------------------------------------------------------------------------
# 3. mutated inputs of `ingest`

NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
TOKENS = ("0", "-1", "1", "2", "3", "7", "100", "2147483647", "2147483648", "-2147483648",
          "9" * 30, "1e308", "-1e308", "1e-320", "nan", "inf", "-inf", "abc", "", "0.5", " ",
          "((0,0,0) (1,1,1) (0,0,0))", "(", ")")


def mutate_text(data, text: str) -> tuple[str, str]:
    lines = text.splitlines(keepends=True)
    op = data.draw(st.sampled_from(("token", "token", "token", "delete", "duplicate", "truncate",
                                    "swap", "garbage")), label="text op")
    i = data.draw(st.integers(0, max(len(lines) - 1, 0)), label="line")
    if op == "token":
        tokens = list(NUMBER.finditer(lines[i])) if lines else []
        if tokens:
            m = data.draw(st.sampled_from(tokens), label="token")
            new = data.draw(st.sampled_from(TOKENS), label="replacement")
            lines[i] = lines[i][:m.start()] + new + lines[i][m.end():]
            return "".join(lines), f"line {i + 1}: {m.group()!r} -> {new!r}"
        op = "delete"
    if op == "delete":
        del lines[i:i + 1]
    elif op == "duplicate":
        lines.insert(i, lines[i])
    elif op == "truncate":
        cut = data.draw(st.integers(0, len(text)), label="length")
        return text[:cut], f"truncated to {cut} chars"
    elif op == "swap":
        j = data.draw(st.integers(0, len(lines) - 1), label="other line")
        lines[i], lines[j] = lines[j], lines[i]
        return "".join(lines), f"swapped lines {i + 1} and {j + 1}"
    else:
        lines[i] = data.draw(st.sampled_from(("garbage\n", "\n", "-\n", "\x00\n", "1 2 3 4 5 6 7\n")),
                             label="garbage")
    return "".join(lines), f"{op} line {i + 1}"


def run_ingest(work, *args, note):
    out = work / "out" / "cells.npz"
    out.parent.mkdir(exist_ok=True)
    proc = cli("ingest", *args, "-o", out, cwd=work, tmpdir=work)
    assert_contract(proc, outputs=[out], dirs=[work, out.parent], note=note)
    return proc


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_ingest_amrex_headers(tmp_path, data):
    work = fresh_dir(tmp_path)
    plot = work / "plt00020"
    shutil.copytree(AMREX, plot)
    target = data.draw(st.sampled_from(("Header", "Level_0/Cell_H", "Level_1/Cell_H",
                                        "Level_2/Cell_H")), label="file")
    text, what = mutate_text(data, (plot / target).read_text())
    (plot / target).write_text(text)
    run_ingest(work, plot, note=f"AMReX {target}: {what}")


ATHENA_ATTRS = {
    "RootGridSize": ([0, 32, 32], [-1, 32, 32], [2**31 - 1] * 3, [33, 32, 32], [16, 16, 16], [32, 32]),
    "MaxLevel": (-1, 0, 1, 3, 31, 100, 2**31 - 1),
    "NumMeshBlocks": (0, 1, 959, 961, -1, 2**31 - 1),
    "MeshBlockSize": ([0, 8, 8], [7, 8, 8], [16, 8, 8], [-8, 8, 8], [8, 8]),
    "NumVariables": ([4], [6], [0], [-1], [5, 1]),
    "VariableNames": ([b"rho"], [b"rho", b"rho", b"vel1", b"vel2", b"vel3"], [b""] * 5,
                      [b"\xff\xfe", b"press", b"vel1", b"vel2", b"vel3"], [b"a"] * 7),
    "DatasetNames": ([b"foo"], [b"prim", b"prim"], []),
    "RootGridX1": ([0.5, -0.5, 1.0], [float("nan"), 0.5, 1.0], [-0.5, 0.5, -1.0], [0.0, 0.0, 1.0],
                   [-1e38, 1e38, 1.0], [-0.5, 0.5, 0.0]),
    "Coordinates": (b"spherical_polar", b"", b"cylindrical"),
}
ATHENA_DATASET_VALUES = {
    "Levels": (-1, 3, 100, 2**31 - 1, 0, 2),
    "LogicalLocations": (-1, 2**40, 2**62, 0, 100, 31),
    "prim": (float("nan"), float("inf"), -1e38),
}


# Datasets the Athena++ fuzzer reshapes.
RESHAPED = ("Levels", "LogicalLocations", "x1f", "x1v")


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_ingest_athena(tmp_path, data):
    import h5py

    work = fresh_dir(tmp_path)
    path = work / "Blast.out2.00001.athdf"
    shutil.copyfile(ATHENA, path)
    edits = []
    with h5py.File(path, "r+") as f:
        for _ in range(data.draw(st.integers(1, 2), label="edits")):
            how = data.draw(st.sampled_from(("attr", "attr", "dataset", "reshape", "delete")),
                            label="how")
            # An earlier edit may have deleted what a later one picks: only present names.
            present = lambda names: sorted(k for k in names if k in f)
            if how in ("dataset", "reshape") and not present(
                    ATHENA_DATASET_VALUES if how == "dataset" else RESHAPED):
                how = "attr"
            if how == "attr":
                key = data.draw(st.sampled_from(sorted(ATHENA_ATTRS)), label="attribute")
                value = data.draw(st.sampled_from(ATHENA_ATTRS[key]), label="value")
                if isinstance(value, list) and value and isinstance(value[0], bytes):
                    value = np.array(value, dtype="S21")
                elif isinstance(value, list):
                    dtype = f.attrs[key].dtype if key in f.attrs else np.int32
                    value = np.array(value, dtype=dtype) if value else np.zeros(0, "S21")
                f.attrs[key] = value
                edits.append(f"attrs[{key}] = {value!r}")
            elif how == "dataset":
                key = data.draw(st.sampled_from(present(ATHENA_DATASET_VALUES)), label="dataset")
                value = data.draw(st.sampled_from(ATHENA_DATASET_VALUES[key]), label="value")
                ds = f[key]
                idx = tuple(data.draw(st.integers(0, n - 1), label="index") for n in ds.shape)
                arr = ds[...]
                arr[idx] = cast(value, arr.dtype)
                ds[...] = arr
                edits.append(f"{key}{list(idx)} = {value}")
            elif how == "reshape":
                key = data.draw(st.sampled_from(present(RESHAPED)), label="dataset")
                arr = f[key][...]
                arr = arr[:-1] if data.draw(st.booleans(), label="drop") else arr.reshape(-1)
                del f[key]
                f.create_dataset(key, data=arr)
                edits.append(f"{key} -> shape {arr.shape}")
            else:
                names = sorted(f.attrs) + sorted(f)
                key = data.draw(st.sampled_from(names), label="delete")
                if key in f.attrs:
                    del f.attrs[key]
                else:
                    del f[key]
                edits.append(f"deleted {key}")
    run_ingest(work, path, note=f"Athena++: {'; '.join(edits)}")


CELL_RECORD = 16  # int32 x, y, z, level


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_ingest_exajet_and_raw(tmp_path, data):
    work = fresh_dir(tmp_path)
    if data.draw(st.booleans(), label="exajet"):
        n = data.draw(st.integers(0, 400), label="records")
        cells = bytearray(GERRIS.read_bytes()[:n * CELL_RECORD])
        scalars = bytearray(GERRIS.with_name("plume7-1.T.scalars").read_bytes()[:n * 4])
        edits = []
        for _ in range(data.draw(st.integers(0, 3), label="edits")):
            which = data.draw(st.sampled_from(("cells", "scalars")), label="file")
            blob = cells if which == "cells" else scalars
            op = data.draw(st.sampled_from(("int", "length", "bytes")), label="op")
            if op == "length":
                delta = data.draw(st.integers(-20, 20), label="delta")
                if delta < 0:
                    del blob[max(len(blob) + delta, 0):]
                else:
                    blob += bytes(range(delta))
            elif blob:
                word = data.draw(st.integers(0, len(blob) // 4 - 1), label="word") \
                    if len(blob) >= 4 else 0
                if op == "int":
                    v = data.draw(st.sampled_from((-1, 1, 3, 31, 32, 100, 2**31 - 1, -(2**31),
                                                   0x7FC00000, 0x7F800000, 2**30)), label="int")
                    blob[word * 4:word * 4 + 4] = int(v).to_bytes(4, "little", signed=v < 0)
                else:
                    blob[word * 4:word * 4 + 4] = data.draw(st.binary(min_size=4, max_size=4))
                edits.append(f"{which} word {word}: {op}")
            if op == "length":
                edits.append(f"{which} length {delta:+d} bytes")
        (work / "small.cells").write_bytes(bytes(cells))
        (work / "small.T.scalars").write_bytes(bytes(scalars))
        extra = data.draw(st.sampled_from(([], ["--field", "T"], ["--nan", "drop"],
                                           ["--nan", "keep"], ["--field", "P"])), label="options")
        run_ingest(work, work / "small.cells", *extra,
                   note=f"ExaJet {n} records: {', '.join(edits)} {extra}")
        return
    dtype = data.draw(st.sampled_from(("uint8", "int8", "uint16", "int16", "uint32", "int32",
                                       "float32", "float64")), label="dtype")
    dims = data.draw(st.one_of(st.tuples(*[st.integers(1, 12)] * 3),
                               st.tuples(*[st.sampled_from((1, 2**20, 2**31 - 1, 2**31, 2**40))] * 3)),
                     label="dims")
    itemsize = np.dtype(dtype).itemsize
    size = int(np.prod(dims, dtype=object)) * itemsize
    nbytes = data.draw(st.sampled_from((size, size, size - 1, size + 1, 0, 7, 4096)) if size < 10**5
                       else st.sampled_from((0, 7, 4096)), label="file bytes")
    nbytes = max(int(nbytes), 0)
    payload = data.draw(st.sampled_from(("random", "zeros", "ramp")), label="payload")
    if payload == "random":
        blob = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1))).bytes(nbytes)
    elif payload == "zeros":
        blob = bytes(nbytes)
    else:
        blob = bytes(i % 251 for i in range(nbytes))
    raw = work / "volume.raw"
    raw.write_bytes(blob)
    extra = data.draw(st.lists(st.sampled_from((
        ["--byte-order", "big"], ["--max-level", "0"], ["--max-level", "40"],
        ["--threshold", "1e30"], ["--threshold", "nan"], ["--threshold", "inf"],
        ["--nan", "zero"], ["--nan", "drop"], ["--nan", "keep"], ["--name", ""])), max_size=2),
        label="options")
    args = [raw, "--format", "raw", "--dims", *dims, "--dtype", dtype] + [a for o in extra for a in o]
    run_ingest(work, *args, note=f"raw {nbytes} bytes ({payload})")


# ---------------------------------------------------------------------------
# 4. render and probe options

FLOATS = st.one_of(
    st.sampled_from(("nan", "inf", "-inf", "0", "-0", "1e-30", "1e30", "5e-324", "1e-310", "1e308",
                     "-1", "0.5", "1", "30", "179.999", "180", "360")),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-50, 50).map(repr),
)
RATES = st.one_of(
    st.sampled_from(("1e-30", "1e30", "5e-324", "1e-310", "1e-45", "1e-7", "0.01", "1", "2", "16",
                     "1000", "0", "-1", "nan", "inf")),
    st.floats(1e-30, 1e30).map(repr),
)


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_render_options(tiny, tmp_path, data):
    work = fresh_dir(tmp_path)
    d = data.draw
    args = ["--size", d(st.integers(1, 64), label="w"), d(st.integers(1, 64), label="h"),
            "--spp", d(st.integers(1, 4), label="spp")]
    vec = st.tuples(FLOATS, FLOATS, FLOATS)
    if d(st.booleans(), label="camera"):
        pos = d(st.one_of(vec, st.just(("20", "15", "10"))), label="position")
        kind = d(st.sampled_from(("free", "equal", "parallel", "none")), label="camera case")
        look = pos if kind == "equal" else d(st.one_of(vec, st.just(("4", "4", "4"))), label="look")
        if kind == "parallel":
            pos, look = ("4", "4", "20"), ("4", "4", "4")
            up = d(st.sampled_from((("0", "0", "1"), ("0", "0", "-3"), ("0", "0", "1e-30"),
                                    ("0", "0", "0"))), label="up")
        else:
            up = d(st.one_of(vec, st.just(("0", "0", "1"))), label="up")
        if kind != "none":
            args += ["--position", *pos, "--look-at", *look, "--up", *up]
        if d(st.booleans(), label="fovy?"):
            args += ["--fovy", d(FLOATS, label="fovy")]
    for opt, strat in (("--sampling-rate", RATES), ("--max-opacity", FLOATS),
                       ("--unit-distance", st.one_of(FLOATS, RATES))):
        if d(st.booleans(), label=f"{opt}?"):
            args += [opt, d(strat, label=opt)]
    if d(st.booleans(), label="range?"):
        lo = d(FLOATS, label="lo")
        hi = d(st.one_of(FLOATS, st.just(lo)), label="hi")
        args += ["--range", lo, hi]
    if d(st.booleans(), label="colormap?"):
        args += ["--colormap", d(st.sampled_from(("viridis", "gray", "nope")), label="cmap")]
        if d(st.booleans(), label="opacity?"):
            args += ["--opacity", d(st.sampled_from(("0,1", "1", "0.5,nan", "", "1,0,1", "2")))]
    args += d(st.sampled_from(([], ["--no-jitter"], ["--shading", "none"], ["--depth"],
                               ["--seed", "4294967295"])), label="flags")
    out = work / d(st.sampled_from(("out.exr", "out.png")), label="output")
    proc = cli("render", *tiny.trio(), "-o", out, *args, cwd=work, tmpdir=work)
    assert_contract(proc, outputs=[out], dirs=[work], note="render options")


def points_file(data, path: Path) -> str:
    """Write a crafted points file at `path`; returns a description."""
    d = data.draw
    kind = d(st.sampled_from(("array", "array", "array", "text", "empty", "npz", "truncated",
                              "huge header", "pickle")), label="points kind")
    if kind == "text":
        path.write_text("1 2 3\n4 5 6\n")
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "npz":
        np.savez(path.with_suffix(".npz"), np.zeros((2, 3)))
        path.with_suffix(".npz").rename(path)
    elif kind == "pickle":
        np.save(path, np.array([[1, 2, 3]], dtype=object), allow_pickle=True)
    elif kind in ("truncated", "huge header"):
        with open(path, "wb") as f:
            np.save(f, np.ones((4, 3)))
        blob = path.read_bytes()
        if kind == "truncated":
            blob = blob[:d(st.integers(0, len(blob) - 1), label="cut")]
        else:
            shape = d(st.sampled_from(("(1099511627776, 3)", "(2305843009213693951, 3)",
                                       "(-1, 3)", "(4, 3, 0)")), label="shape")
            blob = blob.replace(b"(4, 3)", shape.encode())
        path.write_bytes(blob)
    else:
        shape = d(st.sampled_from(((5, 3), (1, 3), (0, 3), (3,), (5, 2), (5, 4), (2, 3, 1), (3, 5),
                                   ())), label="shape")
        dtype = d(st.sampled_from((np.float64, np.float32, np.float16, np.int32, np.int64,
                                   np.uint8, np.bool_, np.complex128, np.dtype(">f8"),
                                   np.dtype("U3"), np.dtype([("x", "f8"), ("y", "f8")]))),
                  label="dtype")
        values = d(st.lists(st.sampled_from((0.5, 3.0, -1.0, 8.5, float("nan"), float("inf"),
                                             float("-inf"), 1e30, -1e38, 1e308, 5e-324, 2.0**31)),
                            min_size=1, max_size=8), label="values")
        n = int(np.prod(shape))
        flat = np.resize(np.array(values), n)
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            try:
                arr = flat.reshape(shape).astype(dtype)
            except (TypeError, ValueError):
                arr = np.zeros(shape, dtype)
        if d(st.booleans(), label="fortran"):
            arr = np.asfortranarray(arr)
        np.save(path, arr)
        return f"points {arr.dtype} {arr.shape} {values}"
    return f"points file: {kind}"


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_probe_points(tiny, tmp_path, data):
    work = fresh_dir(tmp_path)
    pts = work / "points.npy"
    what = points_file(data, pts)
    out = work / "values.npy"
    proc = cli("probe", *tiny.trio(), "--points", pts, "-o", out, cwd=work, tmpdir=work)
    assert_contract(proc, outputs=[out], dirs=[work], note=what)


# ---------------------------------------------------------------------------
# 5. output paths

OUTPUT_KINDS = ("symlink to input", "symlink to new", "directory", "/dev/null", "existing",
                "missing directory", "long name", "newline", "input itself", "hard link to input",
                "symlink loop", "dangling symlink in missing dir")


def output_path(data, work: Path, inp: Path, suffix: str) -> str:
    """The output path of one drawn case (created as the case needs) next to input `inp`."""
    case = data.draw(st.sampled_from(OUTPUT_KINDS), label="output case")
    if case == "symlink to input":
        (work / f"link{suffix}").symlink_to(inp)
        return str(work / f"link{suffix}")
    if case == "symlink to new":
        (work / f"link{suffix}").symlink_to(work / f"target{suffix}")
        return str(work / f"link{suffix}")
    if case == "directory":
        (work / f"dir{suffix}").mkdir()
        return str(work / f"dir{suffix}")
    if case == "/dev/null":
        return "/dev/null"
    if case == "existing":
        (work / f"old{suffix}").write_bytes(b"old contents")
        return str(work / f"old{suffix}")
    if case == "missing directory":
        return str(work / "no" / "such" / f"out{suffix}")
    if case == "long name":
        n = data.draw(st.integers(240, 300), label="name length")
        return str(work / ("x" * (n - len(suffix)) + suffix))
    if case == "newline":  # (a failure naming such a path: test_newline_in_path_error)
        return str(work / f"out\nput{suffix}")
    if case == "input itself":
        return str(inp)
    if case == "hard link to input":
        os.link(inp, work / f"hard{suffix}")
        return str(work / f"hard{suffix}")
    if case == "symlink loop":
        (work / f"loop{suffix}").symlink_to(work / f"loop{suffix}")
        return str(work / f"loop{suffix}")
    (work / f"dangling{suffix}").symlink_to(work / "missing" / f"x{suffix}")
    return str(work / f"dangling{suffix}")


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_output_paths(tiny, tmp_path, data):
    work = fresh_dir(tmp_path)
    tmpdir = fresh_dir(tmp_path)
    command = data.draw(st.sampled_from(("bvh", "render")), label="command")
    inputs = [work / "regions.npz"] if command == "bvh" else \
        [work / f"{k}.npz" for k in ("bricks", "regions", "bvh")]
    for p in inputs:
        shutil.copyfile(tiny.path[p.stem], p)
    suffix = ".npz" if command == "bvh" else data.draw(st.sampled_from((".exr", ".png")))
    target = data.draw(st.sampled_from(inputs), label="input to alias")
    out = output_path(data, work, target, suffix)
    before = {p: sha256(p) for p in inputs}
    existed = os.path.lexists(out)
    was_link = os.path.islink(out)
    old = Path(out).read_bytes() if existed and os.path.isfile(out) and out != "/dev/null" else None
    if command == "bvh":
        args = ["bvh", inputs[0], "-o", out]
    else:
        args = ["render", *inputs, "--size", 8, 8, "-o", out]
    proc = cli(*args, cwd=work, tmpdir=tmpdir)
    note = f"output {out!r}"
    assert_contract(proc, outputs=[] if existed else [out], dirs=[work, Path(out).parent, tmpdir],
                    note=note)
    for p, h in before.items():
        assert sha256(p) == h, f"input {p} changed\n{note}\n{proc.stderr}"
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode), f"/dev/null replaced\n{note}"
    if proc.returncode != 0 and old is not None:
        assert Path(out).read_bytes() == old, f"failed run changed the existing {out}\n{note}"
    if was_link:  # a link stays a link
        assert os.path.islink(out), f"the symbolic link {out} was replaced\n{note}"


@pytest.mark.parametrize("case", ["bvh output in a missing directory", "info of a non-npz file",
                                  "ingest of a missing input"])
def test_newline_in_path_error(tiny, tmp_path, case):
    odd = tmp_path / "no\nsuch"
    if case == "bvh output in a missing directory":
        args, out = ["bvh", tiny.path["regions"], "-o", odd / "bvh.npz"], odd / "bvh.npz"
    elif case == "info of a non-npz file":
        odd.write_text("junk")
        args, out = ["info", odd], None
    else:
        args, out = ["ingest", odd / "x.cells", "-o", tmp_path / "cells.npz"], tmp_path / "cells.npz"
    proc = cli(*args, cwd=tmp_path, tmpdir=tmp_path)
    assert proc.returncode == 1
    assert_contract(proc, outputs=[out] if out else [], dirs=[tmp_path], note=case)


# ---------------------------------------------------------------------------
# signals: a long render ends cleanly on SIGTERM, SIGINT and SIGHUP


@pytest.mark.slow
@pytest.mark.parametrize("signum, status", [(signal.SIGTERM, 143), (signal.SIGINT, 130),
                                            (signal.SIGHUP, 129)])
def test_signal_ends_render_cleanly(gerris, tmp_path, signum, status):
    out = tmp_path / "out.exr"
    env = {k: v for k, v in os.environ.items() if k != "EXABRICKS_DEBUG"}
    env["TMPDIR"] = str(tmp_path)
    proc = subprocess.Popen(
        [sys.executable, "-m", "exabricks.cli.main", "-vv", "render", *gerris.trio(),
         "--size", "2000", "2000", "--spp", "64", "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
        env=env, cwd=tmp_path, start_new_session=True)
    try:
        # The event: the frame has started (a frame of tens of seconds on 2 cores).
        for line in proc.stderr:
            if line.endswith(": rendering\n"):
                break
        assert proc.poll() is None, f"the render ended before the signal: {proc.communicate()}"
        proc.send_signal(signum)
        sent = time.monotonic()
        stdout, stderr = proc.communicate(timeout=30)
        elapsed = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    name = signal.Signals(signum).name
    assert proc.returncode == status, (proc.returncode, stderr)
    assert stderr.strip().splitlines()[-1] == f"error: interrupted ({name})", stderr
    assert elapsed <= 2.0, f"{name}: the process took {elapsed:.2f} s to exit"
    assert not out.exists()
    assert not temporaries(tmp_path)


# ---------------------------------------------------------------------------
# the small JSON inputs (scene, camera, preset, keyframes, camera path) up to the
# caps of exabricks/util/jsonfile.py, and descriptors and FIFOs as inputs and outputs

JSON_SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
                         st.floats(allow_nan=False), st.text(max_size=20))
JSON_VALUES = st.recursive(JSON_SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=10), inner, max_size=6)),
    max_leaves=40)
CAMERA_DOC = {"position": [4, 4, 30], "look_at": [4, 4, 4], "up": [0, 1, 0], "fovy": 30}
JSON_INPUTS = {  # option or command -> (a valid document, how to run it)
    "scene": {"camera": CAMERA_DOC, "volumes": [{"field": "v", "transfer_function":
                                                 {"colormap": "viridis", "opacity": [0, 1]}}],
              "isosurfaces": [{"field": "v", "value": 4.0}]},
    "camera": CAMERA_DOC,
    "transfer-function": {"RGBPoints": [0, 0, 0, 0, 12, 1, 1, 1], "Points": [0, 0, 0.5, 0, 12, 1, 0.5, 0]},
    "keyframes": [CAMERA_DOC, {**CAMERA_DOC, "position": [30, 4, 4]}],
    "camera-path": {"kind": "exabricks camera path", "version": 1, "frames": [CAMERA_DOC]},
}
JSON_PLACES = ("list", "list value", "key", "root")


def mutate_json(data, doc):
    """`doc` with one drawn value replaced: by random JSON, a list of up to twice the
    list cap, a deep nest, or a long string (the sizes a hostile file can reach)."""
    from exabricks.util.jsonfile import MAX_DEPTH, MAX_LIST

    d = data.draw
    big = st.one_of(
        JSON_VALUES,
        st.integers(0, 2 * MAX_LIST).map(lambda n: [0.5] * n),
        st.integers(1, 2 * MAX_DEPTH).map(lambda n: json.loads("[" * n + "]" * n)),
        st.integers(0, 1 << 20).map(lambda n: "x" * n),
        st.integers(0, 40).map(lambda n: [{"field": "v", "value": 1.0}] * n),
    )
    doc = json.loads(json.dumps(doc))
    node, path = doc, []
    while isinstance(node, (dict, list)) and node and d(st.booleans(), label="deeper"):
        key = d(st.sampled_from(sorted(node) if isinstance(node, dict) else range(len(node))))
        path.append(key)
        node = node[key]
    value = d(big, label="value")
    if not path:
        return value, "root"
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = value
    return doc, f"at {path}"


def json_input_path(data, work: Path, text: str) -> Path:
    """Where the drawn JSON input is: a regular file holding `text`, a symbolic link
    to one, a FIFO with no writer, a device or a directory."""
    case = data.draw(st.sampled_from(("file", "file", "file", "link", "fifo", "/dev/zero",
                                      "/dev/null", "directory", "link to /dev/zero")), label="where")
    path = work / "input.json"
    if case in ("file", "link"):
        path.write_text(text)
        if case == "link":
            (work / "link.json").symlink_to(path)
            return work / "link.json"
        return path
    if case == "fifo":
        os.mkfifo(path)
        return path
    if case == "directory":
        path.mkdir()
        return path
    if case == "link to /dev/zero":
        (work / "link.json").symlink_to("/dev/zero")
        return work / "link.json"
    return Path(case)


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_json_inputs(tiny, tmp_path, data):
    work = fresh_dir(tmp_path)
    kind = data.draw(st.sampled_from(sorted(JSON_INPUTS)), label="kind")
    doc, where = mutate_json(data, JSON_INPUTS[kind]) if data.draw(st.booleans(), label="mutate") \
        else (JSON_INPUTS[kind], "valid")
    path = json_input_path(data, work, json.dumps(doc))
    out = work / ("path.json" if kind == "keyframes" else "out.png")
    if kind == "keyframes":
        args = ["camera", "path", path, "--frames", "3", "-o", out]
    else:
        args = ["render", *tiny.trio(), "-o", out, "--size", "8", "8", f"--{kind}", path]
        args += ["--frame", "0"] if kind == "camera-path" else []
    proc = cli(*args, cwd=work, tmpdir=work, timeout=TIMEOUT)
    assert_contract(proc, outputs=[out], dirs=[work], note=f"{kind} {where} via {path}")


DESCRIPTOR_CASES = ("append", "truncate", "pipe", "read-only", "closed", "fd 3", "proc fd 3",
                    "link to stdout", "TMPDIR missing")


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_descriptor_outputs(tiny, tmp_path, data):
    """-o through a descriptor: the bytes land behind it (after what was there, for
    a file opened for appending), or one error line; nothing is replaced."""
    work = fresh_dir(tmp_path)
    case = data.draw(st.sampled_from(DESCRIPTOR_CASES), label="case")
    command = data.draw(st.sampled_from(("bvh", "probe", "render")), label="command")
    target = work / "target"
    target.write_bytes(b"before\n")
    out = {"fd 3": "/dev/fd/3", "proc fd 3": "/proc/self/fd/3", "closed": "/dev/fd/7"}.get(
        case, "/dev/stdout")
    if case == "link to stdout" or command == "render":  # render takes its format from the name
        link = work / ("x.png" if command == "render" else "x.out")
        link.symlink_to(out)
        out = link
    args = {"bvh": ["bvh", tiny.path["regions"]],
            "probe": ["probe", *tiny.trio(), "--points", tiny.points],
            "render": ["render", *tiny.trio(), "--size", "8", "8"]}[command]
    env = {k: v for k, v in os.environ.items() if k != "EXABRICKS_DEBUG"}
    if case == "TMPDIR missing":
        env["TMPDIR"] = str(work / "missing")
    flags = {"append": os.O_WRONLY | os.O_APPEND, "truncate": os.O_WRONLY, "fd 3": os.O_WRONLY,
             "proc fd 3": os.O_WRONLY | os.O_APPEND, "read-only": os.O_RDONLY}
    fd = os.open(target, flags[case]) if case in flags else None
    stdout = subprocess.PIPE if case in ("pipe", "link to stdout", "TMPDIR missing") else \
        (subprocess.DEVNULL if fd is None or case.startswith(("fd", "proc")) else fd)
    try:
        proc = subprocess.run([sys.executable, "-m", "exabricks.cli.main", *map(str, args),
                               "-o", str(out)], stdout=stdout, stderr=subprocess.PIPE,
                              pass_fds=(3,) if case.startswith(("fd", "proc")) else (),
                              preexec_fn=(lambda: os.dup2(fd, 3)) if case.startswith(("fd", "proc"))
                              else None, env=env, timeout=TIMEOUT, cwd=work)
    finally:
        if fd is not None:
            os.close(fd)
    err = proc.stderr.decode(errors="replace")
    note = f"{command} -o {out} ({case})\n{err}"
    assert proc.returncode in (0, 1, 2) and "Traceback" not in err, note
    if proc.returncode == 1:
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: "), note
    if case == "closed":
        assert proc.returncode == 1 and "not open" in err, note
    data_bytes = target.read_bytes()
    if case in ("append", "proc fd 3") and proc.returncode == 0:
        assert data_bytes.startswith(b"before\n") and len(data_bytes) > 7, note
    if case == "read-only":
        assert proc.returncode == 1 and data_bytes == b"before\n", note
    assert not temporaries(work), note


# Magnitudes from float32's smallest subnormal to its largest (issue 65, round 4).
MAGNITUDES = st.one_of(st.sampled_from((1e-45, 1e-39, 1.2e-38, 1e-30, 1.0, 1e30, 3e38)),
                       st.floats(-45, 38.5).map(lambda e: 10.0 ** e))


@pytest.fixture(scope="session")
def plume(gerris):
    import exabricks as eb

    return eb.open(GERRIS, fields=["T"], cache=False)


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_directions_of_any_magnitude(plume, data):
    """A light direction, a slice's or a clip plane's normal or a rotation axis of
    any magnitude draws the frame of the same direction scaled to 1, bit for bit."""
    import exabricks as eb

    d = data.draw
    direction = np.array([d(st.sampled_from((0.0, 1.0, -1.0, 0.3, -0.7)), label=f"d{i}")
                          for i in range(3)])
    if not direction.any():
        direction[0] = 1.0
    magnitude = d(MAGNITUDES, label="magnitude")
    where = d(st.sampled_from(("light", "slice", "clip", "rotate")), label="where")
    (lo, hi) = plume.bounds
    mid = [(a + b) / 2 for a, b in zip(lo, hi)]

    def frame(v):
        v = [float(c) for c in v]
        scene = {"light": dict(integrator="shadow", light=v),
                 "slice": dict(scene={"slices": [{"point": mid, "normal": v, "field": "T"}]}),
                 "clip": dict(scene={"clip": {"planes": [[*mid, *v]]}}),
                 "rotate": dict(scene={"instances": [{"rotate": [*v, 40]}]})}[where]
        return eb.render(plume, field="T", size=(12, 12), seed=3, **scene).rgba

    np.testing.assert_array_equal(frame(direction * magnitude), frame(direction))


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=SUPPRESSED)
@given(data=st.data())
def test_fields_of_any_magnitude(tmp_path, data):
    """A field of any magnitude, as float32 stores it, draws and probes as the same
    stored values scaled by a power of two into float32's normal range (exact)."""
    import exabricks as eb

    magnitude = data.draw(MAGNITUDES, label="magnitude")
    x = np.linspace(-1, 1, 12)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    stored = ((np.exp(-4 * (X ** 2 + Y ** 2 + Z ** 2)) + 0.01) * magnitude).astype(np.float32)
    largest = float(np.abs(stored).max())
    if largest == 0.0:
        return  # nothing float32 can hold: the field is zero
    shift = -np.frexp(largest)[1]
    files = {}
    for name, values in (("given", stored), ("scaled", np.ldexp(stored.astype(np.float64), shift))):
        files[name] = tmp_path / f"{name}.raw"
        values.astype(np.float32).tofile(files[name])
    lo, hi = float(stored.min()), largest
    frames, probes = {}, {}
    points = np.random.default_rng(0).uniform(1, 10, (16, 3))
    for name, factor in (("given", 0), ("scaled", shift)):
        ds = eb.open(files[name], dims=(12, 12, 12), cache=False)
        r = (np.ldexp(lo, factor), np.ldexp(hi, factor)) if hi > lo else None
        frames[name] = eb.render(ds, size=(16, 16), jitter=False, colormap="viridis",
                                 scale="linear", **({"range": r} if r else {})).rgba
        probes[name] = np.ldexp(eb.probe(ds, points).astype(np.float64), -factor)
    assert np.sqrt(np.mean((frames["given"] - frames["scaled"]) ** 2)) < 1e-5
    np.testing.assert_allclose(probes["given"], probes["scaled"], rtol=1e-5,
                               atol=float(np.finfo(np.float32).smallest_subnormal))
