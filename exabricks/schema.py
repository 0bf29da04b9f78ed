"""The public face of the `.npz` file kinds: cells, bricks, regions, bvh, values.

Every file holds plain numeric arrays (loaded with ``allow_pickle=False``) plus
four header entries: ``format`` (the string ``"exabricks"``), ``kind``,
``version`` (an integer bumped on incompatible change) and ``meta`` (a JSON
string: command line, sha256 of the inputs, parameters, statistics, field
names).  Writing validates and goes through a temporary file in the target
directory that is renamed into place; reading validates and refuses a wrong
kind, a future version, a missing array or a wrong dtype with a message that
names the file.  `docs/file-formats.md` documents every array.

Each concept lives in its own module of exabricks.formats; this module imports
and re-exports their public names (use them as `schema.load`, `schema.Bricks`):

- the kinds and their summaries (`Cells`, `Bricks`, `Regions`, `Bvh`, `Values`,
  `world_bounds`, `summary`): exabricks/formats/kinds.py;
- their checks (`validate`, `first_misaligned`, `tree_depth`): formats/checks.py;
- provenance (`sha256_file`, `prefetch_sha256`, `make_meta`, `content_sha256`,
  `built_from`, `check_built_from`): formats/provenance.py;
- memory (`mapping`, `release`, `release_arrays`, `discard`, `trim_heap`, `rows`, `reduce_chunks`,
  `memory_limit`): formats/memory.py;
- the .npz reader (`NpzArchive`) and the header entries: formats/npz.py;
- `save`, `load`, `peek`: formats/files.py.
"""

from __future__ import annotations

from .formats.checks import check_field_names, field_names_problem, first_misaligned, tree_depth, validate
from .formats.files import load, peek, save
from .formats.kinds import KINDS, ArraySpec, Bricks, Bvh, Cells, Kind, Regions, Values, summary, world_bounds
from .formats.memory import (CHUNK, discard, mapping, memory_limit, reduce_chunks, release, release_arrays, rows,
                             trim_heap)
from .formats.npz import FORMAT, HEADER_KEYS, MAX_HEADER_BYTES, NpzArchive
from .formats.provenance import (
    built_from,
    check_built_from,
    content_sha256,
    make_meta,
    prefetch_sha256,
    sha256_file,
)

__all__ = [
    # kinds
    "ArraySpec", "Kind", "Cells", "Bricks", "Regions", "Bvh", "Values", "KINDS", "world_bounds", "summary",
    # checks
    "validate", "check_field_names", "field_names_problem", "first_misaligned", "tree_depth",
    # provenance
    "sha256_file", "prefetch_sha256", "make_meta", "content_sha256", "built_from", "check_built_from",
    # memory
    "CHUNK", "mapping", "release", "release_arrays", "discard", "trim_heap", "rows", "reduce_chunks", "memory_limit",
    # the .npz reader and the header entries
    "FORMAT", "HEADER_KEYS", "MAX_HEADER_BYTES", "NpzArchive",
    # files
    "save", "load", "peek",
]
