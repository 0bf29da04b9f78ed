"""The pacing of a frame's waits on the device (exabricks/engine/pacing.py): each
wait about LAUNCH_SECONDS whatever the spp and size, every row-sample drawn
once, a frame of one sample in bands as before."""

from __future__ import annotations

import pytest

from exabricks.engine.pacing import LAUNCH_SECONDS, Pace

TILE = 8


def _waits(height: int, samples: int, most_rows: int, cost):
    """The waits (rows, samples, seconds) of a frame on a device that takes
    cost(row) seconds for each row-sample of row `row`, as Renderer._draw and
    _band ask for them."""
    pace, waits, row0 = Pace(samples, most_rows, TILE), [], 0
    while row0 < height:
        rows = pace.rows(height - row0)
        done = 0
        while done < samples:
            count = pace.run(rows, done)
            seconds = count * sum(cost(r) for r in range(row0, row0 + rows))
            pace.took(rows * count, seconds)
            waits.append((rows, count, seconds))
            done += count
        row0 += rows
    return waits


@pytest.mark.parametrize("height, samples", [(64, 4096), (256, 256), (256, 1024), (2048, 1), (512, 4)])
def test_every_wait_is_short_whatever_the_spp_and_size(height, samples):
    waits = _waits(height, samples, 256, lambda row: 0.5e-3)  # ~ the path integrator's, 64 wide
    assert sum(rows * count for rows, count, _ in waits) == height * samples
    assert max(seconds for *_, seconds in waits) <= LAUNCH_SECONDS * 1.01


@pytest.mark.parametrize("samples", [1, 16, 4096])
def test_rows_a_hundred_times_dearer_below_the_sky(samples):
    """A band sized on the sky's rows meets the data's: its first run, one sample,
    measures them before the rest of its samples are sized."""
    waits = _waits(256, samples, 256, lambda row: 1e-5 if row < 64 else 1e-3)
    assert sum(rows * count for rows, count, _ in waits) == 256 * samples
    assert max(seconds for *_, seconds in waits) <= LAUNCH_SECONDS * 1.01


def test_a_frame_of_one_sample_grows_its_bands_as_before():
    """32 rows, then each band towards LAUNCH_SECONDS and at most 4 times the last,
    as the renderer's bands were before the pacing."""
    waits = _waits(512, 1, 512, lambda row: 1e-4)
    assert [rows for rows, *_ in waits] == [32, 128, 352]
