"""`exabricks cache info|clear`: the structures that source-taking commands built
and kept, and the BVHs of mesh files (exabricks.cache)."""

from __future__ import annotations

import json
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
                               "sources": [{"key": k, "bytes": size, **about}
                                           for k, size, about in entries]}, sort_keys=True))
        return
    click.echo(f"{store.root}: {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}, "
               f"{_size(total)}")
    for k, size, about in entries:
        options = " ".join(f"{name}={_text(value)}" for name, value in
                           sorted(about.get("options", {}).items()))
        click.echo(f"  {k[:12]}  {_size(size):>9}  {about.get('path', '?')}  {options}".rstrip())


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
    if isinstance(value, (list, tuple)):
        return ",".join(map(_text, value))
    if isinstance(value, dict):
        return ",".join(f"{k}={_text(v)}" for k, v in value.items())
    return str(value)
