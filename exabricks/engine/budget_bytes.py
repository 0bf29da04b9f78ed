"""What a frame under a memory budget holds besides its domains, and what making
and keeping a domain takes beside its bytes (exabricks.engine.streaming;
docs/design-scale.md, "Rendering under a memory budget")."""

from __future__ import annotations

from . import light_volume
from .look import table_bytes

# A domain's bytes (partition.domain_bytes) times this must fit the budget left
# after the images: while a domain is made, its copies from the files, its
# validation, the BVH builder and the upload take about as much again
# (measured: docs/benchmarks-decisions.md, "Measurements behind design choices").
SLACK = 2.5
# Bytes per brick of the whole dataset that making a domain holds whatever its
# size (partition.domain_data: a mask of the bricks listed and their renumbering).
PER_BRICK = 5
# A resident domain kept beside the one being made counts this many times its
# bytes (partition.domain_bytes): what the estimate misses (about 4 % and 83 KiB
# a domain on the thin shells) and the heap the makes leave behind. Counted
# once, a 16 MiB budget's tiled frame of the thin shells peaked at the budget;
# twice, within it (docs/benchmarks-scale.md, "Domains kept across samples, bands and
# frames").
HELD = 2
# Copies of a frame's transfer-function lookup tables (look.table_bytes) while
# a domain draws: the transfer function's own, the look's host array and its
# device buffer. A log-scaled function's irregular knots take tables of up to
# 1 MiB a layer.
TABLE_COPIES = 3
# The share of a budget that the shadow integrator's cached transmittance may take
# (at most its own bound, light_volume.MAX_NODES): the domains share one, over the
# whole dataset (docs/design-rendering.md, "Lights and shadows").
LIGHT_SHARE = 0.25


def image_bytes(scene, tile=None) -> int:
    """Host bytes of the images a streamed frame keeps (the composite, the sum of
    the samples, the domain's result and a copy offered to on_image): whole
    frames, or bands of whole rows of a tile's height with `tile` (W, H)."""
    width, height = int(scene.settings.width), int(scene.settings.height)
    rows = height if tile is None else min(int(tile[1]), height)
    return 4 * width * rows * 16


def fixed_bytes(scene, n_bricks: int, tile=None, budget: int | None = None) -> int:
    """Host bytes a budgeted frame of `scene` holds whatever its domains: the
    images (image_bytes), the transfer-function lookup tables while a domain
    draws (TABLE_COPIES), the indices over the dataset's `n_bricks` bricks
    (PER_BRICK) and, under the shadow integrator, its cached transmittance
    (light_bytes, of `budget`)."""
    return (image_bytes(scene, tile) + TABLE_COPIES * table_bytes(scene) + PER_BRICK * n_bricks
            + (light_bytes(scene, budget) if budget else 0))


def light_bytes(scene, budget: int) -> int:
    """The bytes of the shadow integrator's cached transmittance (light_volume)
    that a frame of `scene` under `budget` holds: a share of it (LIGHT_SHARE),
    at most the volume's own bound; 0 for frames that cache none."""
    return int(min(4 * light_volume.MAX_NODES, budget * LIGHT_SHARE)) if light_volume.cached(scene) else 0
