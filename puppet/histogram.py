"""Histogram: per-frame times in bounded memory (a fixed-width bin count, not a list).

A run of any length keeps ``BINS`` counters per series (80 kB): an hour of ``live`` at 60 fps
(216 000 frames) costs what one frame does. Percentiles read the two order statistics around
their rank from the bins (each placed linearly inside its bin) and interpolate between them as
numpy does, so they are within one bin (0.05 ms) of the exact ones below ``RANGE_MS``, a long
tail's gaps included; a value above it lands in the last bin, which reports the largest value
seen.
Any non-negative value with that resolution fits the same bins: ``perform`` keeps its tracking
errors (degrees) in one, so a looping show of a day costs what one cycle does.
"""

from __future__ import annotations

import math

import numpy as np

BIN_MS = 0.05
"""Width of one bin, milliseconds (a percentile is within one bin of the exact value)."""
RANGE_MS = 1000.0
"""Values up to this many milliseconds are binned exactly; larger ones share the last bin."""
BINS = int(RANGE_MS / BIN_MS) + 1


class Histogram:
    """Counts of millisecond values in BINS fixed bins, plus their count, sum, min and max.

    ``add(ms)`` per frame (no allocation); ``percentile(q)`` (q in 0..100), ``mean``, ``count``.
    Negative values (a clock step) count as 0.
    """

    __slots__ = ("counts", "count", "total", "low", "high")

    def __init__(self):
        self.counts = np.zeros(BINS, np.int64)
        self.count = 0
        self.total = 0.0
        self.low = math.inf
        self.high = -math.inf

    def add(self, ms: float) -> None:
        ms = max(float(ms), 0.0)
        self.counts[min(int(ms / BIN_MS), BINS - 1)] += 1
        self.count += 1
        self.total += ms
        if ms < self.low:
            self.low = ms
        if ms > self.high:
            self.high = ms

    def add_each(self, values) -> None:
        """``add`` every value of a 1-D array (a cycle's servos)."""
        for value in values.tolist():
            self.add(value)

    def __len__(self) -> int:
        return self.count

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else float("nan")

    def percentile(self, q: float) -> float:
        """The q-th percentile (as numpy's default: linear between the two order statistics
        around the rank), each order statistic read from the bins (its bin, placed linearly
        inside it, kept within [min, max] seen): within one bin of the exact value below
        RANGE_MS, even across a gap in a long tail."""
        if not self.count:
            return float("nan")
        rank = q / 100.0 * (self.count - 1)  # 0-based fractional rank
        cumulative = np.cumsum(self.counts)
        j = math.floor(rank)
        value = self._order_statistic(cumulative, j)
        if rank > j and j + 1 < self.count:
            value += (rank - j) * (self._order_statistic(cumulative, j + 1) - value)
        return value

    def _order_statistic(self, cumulative: np.ndarray, j: int) -> float:
        """The j-th smallest value (0-based), from the bins."""
        b = int(np.searchsorted(cumulative, j, side="right"))
        if b >= BINS - 1:
            return self.high
        below = int(cumulative[b - 1]) if b else 0
        inside = (j - below + 0.5) / self.counts[b]  # its place among the bin's values
        value = (b + min(max(inside, 0.0), 1.0)) * BIN_MS
        return min(max(value, self.low), self.high)
