"""`exabricks cache info|clear`: the structures that source-taking commands built
and kept, and the BVHs of mesh files (exabricks.cache)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import click

_root = click.option("--cache", "root", default=None, metavar="DIR", type=click.Path(file_okay=False),
                     help="The cache [default: $EXABRICKS_CACHE, else $XDG_CACHE_HOME/exabricks, "
                     "else ~/.cache/exabricks].")


def _store(root):
    from ..cache import Cache, default_root

    return Cache(Path(root) if root is not None else default_root())


@click.group()
def cache():
    """The structures built from sources by `render SOURCE` and `probe SOURCE`, and the
    BVHs of `render --mesh` files."""


@cache.command()
@_root
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def info(root, as_json):
    """Where the cache is, its entries (source, options, size) and their total size."""
    store = _store(root)
    entries = store.entries()
    total = sum(size for _, size, _ in entries)
    if as_json:
        click.echo(json.dumps({"root": str(store.root), "entries": len(entries), "bytes": total,
                               "sources": [{**_finite(about), "key": k, "bytes": size}
                                           for k, size, about in entries]},
                              sort_keys=True, allow_nan=False))
        return
    click.echo(f"{_escaped(str(store.root))}: {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}, "
               f"{_size(total)}")
    for k, size, about in entries:
        options = about.get("options")
        options = " ".join(f"{_text(name)}={_text(value)}" for name, value in
                           sorted(options.items())) if isinstance(options, dict) else ""
        click.echo(f"  {k[:12]}  {_size(size):>9}  {_text(about.get('path', '?'))}  "
                   f"{options}".rstrip())


@cache.command()
@_root
def clear(root):
    """Remove every entry (and unfinished builds); nothing else under the cache."""
    store = _store(root)
    n, freed = store.clear()
    click.echo(f"{store.root}: removed {n} entr{'y' if n == 1 else 'ies'}, {_size(freed)}")


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


def _text(value) -> str:
    """`value` (any JSON value of an entry.json) as one line of text."""
    if isinstance(value, (list, tuple)):
        return ",".join(map(_text, value))
    if isinstance(value, dict):
        return ",".join(f"{_text(k)}={_text(v)}" for k, v in value.items())
    return _escaped(str(value))


# Control characters (a newline would forge an output line), line and paragraph
# separators, and lone surrogates (a path's undecodable bytes) are written escaped.
_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\ud800-\udfff]")


def _escaped(text: str) -> str:
    return _UNPRINTABLE.sub(lambda m: m.group().encode("unicode_escape", "backslashreplace")
                            .decode("ascii") if not 0xD800 <= ord(m.group()) <= 0xDFFF
                            else f"\\u{ord(m.group()):04x}", text)


def _finite(value):
    """`value` with every non-finite number (which JSON cannot hold) as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value
