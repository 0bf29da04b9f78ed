"""The OpenCL side of rendering: the dataset on a device (`device_data`), the
renderer and its frames (`renderer`), cell location, level of detail and the
vertex reconstruction, and rendering under a memory budget (`partition`,
`streaming`). The render job that chooses among them is exabricks.stages.render."""

from ..util import numba_compiles

numba_compiles.announce()  # the majorants, level of detail and vertex values compile with numba
