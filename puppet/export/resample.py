"""Resampling a take's irregular readings to a fixed frame rate.

Frame k (k = 1, 2, ...) shows take time ``t_first + round((k − 1) · 1e9 / fps)`` ns: frame 1 is
the first reading, and frames follow every 1/fps seconds up to the last reading. Each servo's
ticks are interpolated linearly between the two readings around the frame's time, along the
shorter way round the encoder (a jump of more than half a turn between two readings is taken as
a wrap, never as a fast spin), and rounded to whole ticks. The result is a pure function of the
take's timestamps and ticks: the same take and fps give the same frames on every run.
"""

from __future__ import annotations

import math

import numpy as np

from puppet.export.errors import ExportError
from puppet.reading import Reading
from puppet.servo_models import HALF_TURN, TICKS_PER_TURN


def check_fps(fps, where="--fps") -> float:
    """fps as a float, or ExportError unless it is a finite number > 0."""
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise ExportError(where, f"frames per second must be a number, got {fps!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise ExportError(where, f"frames per second must be > 0, got {fps!r}")
    return value


def frame_offsets_ns(duration_ns: int, fps: float) -> np.ndarray:
    """(N,) int64 ns after the first reading of frames 1..N: round((k−1)·1e9/fps) <= duration."""
    fps = check_fps(fps)
    step = 1e9 / fps
    count = int(duration_ns // step) + 1
    while round(count * step) <= duration_ns:  # guard the float division at the boundary
        count += 1
    while count > 1 and round((count - 1) * step) > duration_ns:
        count -= 1
    return np.rint(np.arange(count) * step).astype(np.int64)


class Resampler:
    """Readings of a take at a fixed frame rate.

    t_ns:  (R,) int64 reading times, non-decreasing (R >= 1).
    ticks: (R, k) int32 continuous encoder counts, one column per servo.
    ok:    (R, k) bool, False where a servo's read failed (its ticks hold the last good value).
    ids:   (k,) servo ids, shared by every Reading yielded.
    fps:   output frames per second (> 0).
    Fields: times_ns (N,) int64 take time of each frame; len() = N.
    Iterating yields one Reading per frame: ticks interpolated, ok = both neighbours ok.
    """

    def __init__(self, t_ns, ticks, ok, ids, fps: float, *, source="take"):
        self.fps = check_fps(fps)
        t = np.asarray(t_ns, np.int64)
        if t.ndim != 1 or len(t) == 0:
            raise ExportError(source, "the take holds no readings")
        back = np.flatnonzero(np.diff(t) < 0)
        if back.size:
            i = int(back[0]) + 1
            raise ExportError(source, f"reading {i} is timed before reading {i - 1} "
                                      f"({t[i]} < {t[i - 1]} ns): readings must be in time order")
        self.t_ns = t
        self.ticks = np.asarray(ticks, np.int64)
        self.ok = np.asarray(ok, bool)
        self.ids = np.asarray(ids)
        self.times_ns = t[0] + frame_offsets_ns(int(t[-1] - t[0]), self.fps)
        # Reading i at or before each frame time, and the weight of reading i + 1.
        self._index = np.searchsorted(t, self.times_ns, side="right") - 1
        nxt = np.minimum(self._index + 1, len(t) - 1)
        span = (t[nxt] - t[self._index]).astype(np.float64)
        elapsed = (self.times_ns - t[self._index]).astype(np.float64)
        self._alpha = np.where(span > 0, elapsed / np.where(span > 0, span, 1.0), 0.0)
        self._next = nxt

    def __len__(self) -> int:
        return len(self.times_ns)

    def ticks_at(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """(ticks (k,) int32, ok (k,) bool) of frame index ``frame`` (0-based: frame 1 is 0)."""
        i, j, a = self._index[frame], self._next[frame], self._alpha[frame]
        start = self.ticks[i]
        if a == 0.0:
            return start.astype(np.int32), self.ok[i].copy()
        step = (self.ticks[j] - start + HALF_TURN) % TICKS_PER_TURN - HALF_TURN  # short way round
        ticks = start + np.floor(a * step + 0.5).astype(np.int64)
        return ticks.astype(np.int32), self.ok[i] & self.ok[j]

    def __iter__(self):
        for f in range(len(self)):
            ticks, ok = self.ticks_at(f)
            yield Reading(t_ns=int(self.times_ns[f]), ids=self.ids, ticks=ticks, ok=ok)
