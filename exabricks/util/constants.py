"""Dtypes chosen once for every array the stages exchange."""

import numpy as np

# Lattice coordinates are in finest-cell units; int32 covers 2**31 finest cells per axis.
LATTICE_DTYPE = np.dtype(np.int32)
# Level 0 is the finest; a level-l cell is 2**l lattice units wide. 31 levels is plenty.
LEVEL_DTYPE = np.dtype(np.int8)
MAX_LEVEL = 30
# Every scalar field is stored and rendered in float32 (the paper's choice).
VALUE_DTYPE = np.dtype(np.float32)
# Offsets into flat per-brick value arrays and CSR arrays may exceed 2**31.
OFFSET_DTYPE = np.dtype(np.int64)
# Brick, region and node ids: 2**31 of each is far beyond one machine's memory.
INDEX_DTYPE = np.dtype(np.int32)
# Region and BVH bounds sit on half-lattice positions (a support extends w/2 past a
# cell), which float32 represents exactly up to 2**23 lattice units.
BOUNDS_DTYPE = np.dtype(np.float32)
# Origin and spacing of the world frame, taken from the simulation file.
WORLD_DTYPE = np.dtype(np.float64)
# Depth of every tree a kernel descends (BVH over regions, tree over brick
# supports): the kernels' private stacks hold this many deferred nodes
# (kernel_abi EB_STACK_SIZE), and every tree is checked against it on load.
MAX_TREE_DEPTH = 64
# The default --max-brick-width: bricks at most this many cells wide per axis
# (`brick`), and the width whose partition a cells file's piece runs are nodes of.
MAX_BRICK_WIDTH = 32
# The largest magnitude a float32 holds: the kernels read every float setting, camera
# coordinate and data range as float32, so a value beyond it is refused (it would
# overflow to infinity there).
FLOAT32_MAX = float(np.finfo(np.float32).max)
# The largest radiance a lit sample may carry (exabricks.scene.model's check of the
# lights and the exposure): float32's range less room for summing 4096 samples of
# a pixel and the compositing of layers, a million-fold.
MAX_RADIANCE = FLOAT32_MAX * 1e-6
# Largest world coordinate a mesh vertex or an instance's mirror or translation may
# hold: beyond it, float32 ray arithmetic overflows.
MAX_COORDINATE = 1e30
# Central differences step this many cells of the finest level at the point along
# each axis (kernels/frame.cl): half a cell for volume samples (--gradient central,
# the nearest reconstruction's face normals), a whole cell for iso-surface normals,
# which averages the reconstruction's cell-scale terraces away (docs/design-rendering.md,
# "Integration and images").
CENTRAL_STEP_CELLS = 0.5
ISO_CENTRAL_STEP_CELLS = 1.0
# Samples one ray may take (per pixel sample): a sampling rate that would need
# more is refused before rendering (and bounds every kernel loop).
MAX_SAMPLES_PER_RAY = 1 << 20
# Knots of one transfer-function list (RGBPoints or Points). ParaView's presets
# and matplotlib's tables have at most a few hundred; the cap bounds the cost of
# checking a hostile preset and the image metadata that embeds it.
MAX_KNOTS = 4096
# Characters of an annotated picture's title: one line above the frame, which the
# picture widens to hold (200 characters at the title's size are about 2,000 pixels
# beside a 512-pixel frame); a longer text is refused, not drawn for minutes into a
# picture hundreds of thousands of pixels wide.
MAX_TITLE_CHARS = 200

# ingest's vocabulary (exabricks.stages.ingest), here so that the command line declares
# ingest's options without importing the stage.
NAN_POLICIES = ("error", "zero", "drop", "keep")
"""What `validate_cells` does with NaN or +-Inf values.

error: refuse the input, naming the field and the first cell (the default);
zero:  replace every non-finite value by 0;
drop:  remove every cell that has a non-finite value in any field (leaves holes,
       which the reconstruction treats as empty space);
keep:  store them unchanged (the renderer then sees NaN/Inf; use with care).
"""


AUTO_MASK_FIELD = "volFrac"
"""The field that masks cells by itself: where an input has it and no mask is given
(and the automatic rule is not turned off), cells with volFrac == 0 are dropped.
AMReX embedded-boundary plotfiles store the fluid volume fraction of each cell
under this name; 0 is inside the body."""
