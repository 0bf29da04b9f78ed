"""Data-parallel rendering (exabricks.engine.partition, issue 12): the domains of a
k-d partition each render exactly their samples, and their images composited
front to back in visibility order give the whole frame, in process (the MPI
runs are tests/engine/test_mpi.py).

The same samples are taken at the same positions from the same bricks, so the
composite differs from the one-domain frame by float rounding only; the bound
is the issue's, RMSE at most 1e-5 of the maximum, with early ray termination
off (a domain cannot know the opacity in front of it)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from exabricks.engine.device_data import DatasetScale
from exabricks.engine.domains import _meeting, domain_data, domain_options, region_blocks
from exabricks.engine.partition import composite, eye_lattice, kd_partition
from exabricks.engine.renderer import Renderer
from exabricks.film.film import over_background

from helpers import device_param
from helpers.frames import DATASETS, loaded, renderer, scene_for

# What a domain can render alone (exabricks.engine.partition.needs_image_mode: iso-surfaces,
# AO, depth and the vertex reconstruction take image mode).
# clip-slice and lod build program variants of their own, the slowest of the fast
# suite on a fresh machine: the slow suite runs them.
MODES = ("emission", "central", "two-layers", "clip-slice", "lod", "spp", "nearest")
SLOW_MODES = ("clip-slice", "lod")


@functools.lru_cache(maxsize=None)
def domains(name: str, n: int, device, options: tuple):
    built = loaded(name)[0]
    part = kd_partition(built.bricks, built.regions, n)
    fields = DATASETS[name][1]
    scale = DatasetScale.of(built.bricks, fields)
    renderers = []
    for k in range(n):
        box = (part.lower[k], part.upper[k])
        renderers.append(Renderer(*domain_data(built.bricks, built.regions, *box, **dict(options)),
                                  fields=fields, device=device, domain=box, scale=scale))
    return part, renderers


def composited(name: str, n: int, device, scene):
    """The frame as data-parallel ranks make it: every sample index of every domain,
    composited in visibility order, averaged, then over the background."""
    built = loaded(name)[0]
    part, renderers = domains(name, n, device,
                                tuple(domain_options(built.bricks, scene).items()))
    plain = scene.replace(background=(0.0, 0.0, 0.0, 0.0))
    order = part.visibility_order(eye_lattice(built.bricks, scene.camera.position))
    spp = scene.settings.spp
    total, samples = None, 0
    for s in range(spp):
        results = [r.render_scene(plain, sample=s if spp > 1 else None) for r in renderers]
        samples += sum(r.stats["samples"] for r in results)
        image = results[order[0]].rgba.copy()
        for k in order[1:]:
            composite(image, results[k].rgba)
        total = image if total is None else total + image
    return over_background(total / np.float32(spp), scene.background), samples


def no_termination(scene):
    return scene.replace(settings=dataclasses.replace(scene.settings, max_opacity=1.0))


# So does Athena++'s nearest frame (the slowest; the mode stays on the others).
CASES = [pytest.param(name, mode, marks=pytest.mark.slow)
         if mode in SLOW_MODES or (name, mode) == ("athena", "nearest") else (name, mode)
         for name in sorted(DATASETS) for mode in MODES]


@device_param
@pytest.mark.parametrize("name,mode", CASES)
def test_domains_composite_to_the_whole_frame(name, mode, device):
    scene = no_termination(scene_for(name, mode))
    whole = renderer(name, device).render_scene(scene)
    for n in (2, 3):
        image, samples = composited(name, n, device, scene)
        b = whole.rgba
        assert b[..., 3].max() > 1e-3
        rmse = float(np.sqrt(np.mean((image - b) ** 2)))
        assert rmse <= 1e-5 * float(np.abs(b).max()), (n, rmse)
        # every sample of the whole frame (and those behind a fully opaque point,
        # where even max opacity 1 ends a ray, which a domain behind cannot know)
        assert samples >= whole.stats["samples"], (n, samples, whole.stats["samples"])


@pytest.mark.parametrize("name", sorted(DATASETS))
@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
def test_domains_tile_space_and_share_the_bytes(name, n, rng):
    built = loaded(name)[0]
    part = kd_partition(built.bricks, built.regions, n)
    assert part.n_domains == n
    lo = built.regions.lower_lattice.min(axis=0)
    hi = built.regions.upper_lattice.max(axis=0)
    points = rng.uniform(lo - 5, hi + 5, (4000, 3))
    points[:50] = np.round(points[:50])  # on lattice planes, where the cuts are
    inside = ((points[:, None, :] >= part.lower[None]) & (points[:, None, :] < part.upper[None]))
    np.testing.assert_array_equal(inside.all(axis=2).sum(axis=1), 1)
    sizes = []
    for k in range(n):
        b, r, v = domain_data(built.bricks, built.regions, part.lower[k], part.upper[k])
        sizes.append(b.values.nbytes + r.brick_ids.nbytes + 34 * r.n_regions)
    total = built.bricks.values.nbytes + built.regions.brick_ids.nbytes + 34 * built.regions.n_regions
    # about 1/n each: balanced, and little held twice (the regions across a cut go
    # to both sides, and the bricks they list keep a cell beyond it)
    assert max(sizes) <= 1.3 * np.mean(sizes), (sizes, total)
    assert sum(sizes) <= 1.4 * total, (sizes, total)


@pytest.mark.parametrize("name", sorted(DATASETS))
def test_region_blocks_find_the_same_regions_as_a_pass_over_all(name, rng):
    """The block index (`region_blocks`) that spares a budgeted render a pass over
    every region per domain finds exactly the regions a full pass finds."""
    regions = loaded(name)[0].regions
    blocks = region_blocks(regions)
    lo = regions.lower_lattice.min(axis=0).astype(np.float64)
    hi = regions.upper_lattice.max(axis=0).astype(np.float64)
    for _ in range(40):
        a, b = np.sort(rng.uniform(lo - 2, hi + 2, (2, 3)), axis=0)
        np.testing.assert_array_equal(_meeting(regions, a, b, blocks), _meeting(regions, a, b))
    np.testing.assert_array_equal(_meeting(regions, lo - 1, hi + 1, blocks),
                                  np.arange(regions.n_regions))


@pytest.mark.parametrize("n", [2, 3, 7])
def test_visibility_order_is_front_to_back_on_every_ray(n, rng):
    built = loaded("amrex")[0]
    part = kd_partition(built.bricks, built.regions, n)
    lo = built.regions.lower_lattice.min(axis=0)
    hi = built.regions.upper_lattice.max(axis=0)
    for _ in range(20):
        eye = rng.uniform(lo - 200, hi + 200)
        rank = {p: i for i, p in enumerate(part.visibility_order(eye))}
        assert sorted(rank) == list(range(n))
        target = rng.uniform(lo, hi)
        t = np.linspace(0, 1, 2000)[:, None]
        points = eye + t * (target - eye)
        inside = ((points[:, None, :] >= part.lower[None]) & (points[:, None, :] < part.upper[None]))
        along = inside.all(axis=2).argmax(axis=1)  # the domain of each point, eye to target
        seen = [rank[int(p)] for p in along]
        assert seen == sorted(seen)


def _brick_cells(bricks, b):
    nx, ny, nz = (int(d) for d in bricks.dims[b])
    return bricks.values[:, bricks.offset[b]:bricks.offset[b] + nx * ny * nz].reshape(-1, nz, ny, nx)


@pytest.mark.parametrize("crop", [False, True])
def test_domain_data_keeps_every_region_that_meets_the_domain(crop):
    built = loaded("amrex")[0]
    whole_b, whole_r = built.bricks, built.regions
    part = kd_partition(whole_b, whole_r, 4)
    for k in range(4):
        b, r, _ = domain_data(whole_b, whole_r, part.lower[k], part.upper[k], crop=crop)
        meets = (np.all(whole_r.lower_lattice < part.upper[k], axis=1)
                 & np.all(whole_r.upper_lattice > part.lower[k], axis=1))
        assert r.n_regions == int(meets.sum())
        for i, src in enumerate(np.flatnonzero(meets)):
            old = whole_r.brick_ids[whole_r.brick_start[src]:whole_r.brick_start[src + 1]]
            new = r.brick_ids[r.brick_start[i]:r.brick_start[i + 1]]
            if not crop:
                assert len(old) == len(new)
            # the list is the whole list less the bricks cropped away, in order; each
            # kept brick is a box of cells of its original, values included
            j = 0
            for m in new:
                while not (whole_b.level[old[j]] == b.level[m] and np.all(
                        whole_b.lower_lattice[old[j]] <= b.lower_lattice[m])
                        and np.all(b.lower_lattice[m] + b.dims[m] * 2 ** int(b.level[m])
                                   <= whole_b.lower_lattice[old[j]]
                                   + whole_b.dims[old[j]] * 2 ** int(whole_b.level[old[j]]))):
                    j += 1
                o = old[j]
                first = (b.lower_lattice[m] - whole_b.lower_lattice[o]) // 2 ** int(b.level[m])
                x0, y0, z0 = (int(v) for v in first)
                nx, ny, nz = (int(v) for v in b.dims[m])
                np.testing.assert_array_equal(
                    _brick_cells(whole_b, o)[:, z0:z0 + nz, y0:y0 + ny, x0:x0 + nx],
                    _brick_cells(b, m))
                j += 1
