"""How a frame's work is cut into waits on the device short enough for a signal
to end the run within a second (docs/design.md, "Errors, hostile input, outputs
and signals").

Python runs a signal's handler only between bytecodes, so while the host waits
for the device (a launch's event, the read-back of a band) a SIGTERM waits
too. The renderer draws a frame in bands of whole rows, and each band's
samples per pixel in launches, one kernel launch per sample; it waits for the
device after every few launches and checks for a signal there. `Pace` sizes
both from measured times (the last band's, and the band's first sample's), so
that each wait lasts about LAUNCH_SECONDS whatever the integrator, frame size
and spp: in bands of all their samples, a 64 x 64 frame of the path
integrator at 4096 spp took 27 to 76 s to stop.

The unit of work is a row-sample: one row of the band, one sample per pixel.
Where a band of at least `tile` rows with all its samples fits in one wait,
the band is drawn whole (after its first sample, below; a frame of one sample
is paced as before); else the band is as many rows as one sample's launch of
them fits (large launches keep the device's cores busy) and its samples go in
runs. A band's first run is one sample: its rows may cost far more than the
rows above them, and its time sizes the runs after it. Samples stay in order
within each pixel, so the image is the same bit for bit however the work is
cut.
"""

from __future__ import annotations

import time

from ..util import interrupt, progress

# Seconds of device work between two checks for a signal. A band's end (and its
# first sample's) idles a core while the other finishes (2-5 % of a frame at
# 0.1 s bands, docs/benchmarks-decisions.md, "Cell location and render bands");
# the runs between are queued ahead of the wait (Renderer._band).
LAUNCH_SECONDS = 0.25
# A band is at most this many times the last band's work: the first rows (often
# empty sky) can be much cheaper than the rows below them.
GROWTH = 4.0


class Pace:
    """Rows of each band and samples of each wait of a frame whose bands take
    `samples` samples per pixel, at most `most_rows` rows (a multiple of
    `tile`, the rows of a work-group) each."""

    def __init__(self, samples: int, most_rows: int, tile: int):
        self.samples = int(samples)
        self.most_rows = int(most_rows)
        self.tile = int(tile)
        self.units = 4 * self.tile  # row-samples of the next band's first wait: four tiles' rows of one sample
        self.cost = 0.0  # seconds per row-sample of the last wait
        self.band = [0, 0.0]  # row-samples and seconds of the band so far

    def rows(self, left: int) -> int:
        """Rows of the next band, where `left` rows remain to be drawn: sized from
        the last band's time towards LAUNCH_SECONDS, at most GROWTH times its work."""
        units, seconds = self.band
        if units:
            scale = GROWTH if seconds <= 0 else min(GROWTH, LAUNCH_SECONDS / seconds)
            self.units, self.band = max(1, int(units * scale)), [0, 0.0]
        whole = self.units // self.samples if self.units >= self.tile * self.samples else self.units
        rows = max(self.tile, whole // self.tile * self.tile)
        return min(rows, self.most_rows, left)

    def run(self, rows: int, done: int) -> int:
        """Samples of the next wait on a band of `rows` rows of which `done` samples
        are drawn. The first is one sample: these rows may cost far more than the
        rows above them (sky, then the data), and its time sizes the rest, at the
        cost it measured (the same rows: no growth bound)."""
        if not done:
            return 1
        fits = LAUNCH_SECONDS / self.cost / rows if self.cost > 0 else self.samples
        return max(1, min(self.samples - done, int(fits)))

    def took(self, units: int, seconds: float) -> None:
        """A wait that drew `units` row-samples of the band took `seconds`."""
        seconds = max(seconds, 0.0)
        self.cost = seconds / units
        self.band[0] += units
        self.band[1] += seconds

    def waited(self, event, units: int, since: float) -> float:
        """Wait for the run of `units` row-samples whose last launch is `event` (the
        device has drawn it since `since`), take its time, raise a signal that came
        meanwhile (exabricks.util.interrupt), redraw the progress bar on a terminal;
        the time it ended."""
        event.wait()
        now = time.perf_counter()
        self.took(units, now - since)
        interrupt.raise_pending()
        progress.tick()  # a long frame's bar keeps its clock going on a terminal
        return now


# A frame is rendered in bands of whole rows (their samples paced by Pace), and a
# band's device buffers never exceed BAND_BYTES.
BAND_BYTES = 64 << 20


def band_rows(device, width: int, height: int, tile: int) -> int:
    """Most rows of one band (a multiple of `tile`), from the buffer limits."""
    largest = min(int(device.max_mem_alloc_size), BAND_BYTES)
    rows = max(tile, largest // (16 * width) // tile * tile)
    return min(rows, -(-height // tile) * tile)
