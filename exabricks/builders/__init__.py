"""The builders of cells, bricks, regions and the BVH (numba): their first run on a
machine compiles them, which a progress bar then says (exabricks.util.numba_compiles)."""

from ..util import numba_compiles

numba_compiles.announce()
