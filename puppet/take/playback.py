"""PlaybackClock: turns a take's timestamped readings into frames at a fixed output rate."""

from __future__ import annotations

import time
from typing import Callable, Iterable, Iterator, NamedTuple

import numpy as np

from puppet.reading import Reading

MAX_GAP_S = 1.0  # a longer gap between two readings plays as this long (a stalled bus, damage)


class PlaybackFrame(NamedTuple):
    """One output frame of a playback.

    index:     output frame number, from 0.
    t_s:       output time of the frame, seconds since the first frame (index / fps).
    take_t_ns: take time the frame shows, monotonic ns of the take's clock.
    reading:   the reading shown (shared between frames that hold the same reading).
    """

    index: int
    t_s: float
    take_t_ns: int
    reading: Reading


class PlaybackClock:
    """Frames at a fixed output fps from a take's readings; a pure function of the timestamps.

    Output frame i shows take time t_first + start_s + i * speed / fps: at speed 0.5 a take
    plays twice as long. No wall clock is read (see pace() for real-time display).
    A gap between two readings longer than max_gap_s is cut to max_gap_s (and listed in cuts),
    so no timestamp, however wrong, makes a playback run on for hours.

    readings: iterable of Reading in time order (a TakeReader, or its readings()).
    fps:      output frames per second.
    speed:    take seconds per output second (> 0).
    mode:     "hold": the latest reading at or before the frame's take time (sample and hold);
              "nearest": the reading nearest in time (ties go to the earlier one).
    start_s, end_s: take time span to play, seconds from the first reading (end_s None: to
              the last reading), on the take's time line after gaps are cut.
    max_gap_s: longest gap between readings played as it is, seconds (> 0).
    cuts:     (take t_ns where the gap starts, gap ns) of every gap cut so far by iteration.
    """

    def __init__(
        self,
        readings: Iterable[Reading],
        *,
        fps: float = 60.0,
        speed: float = 1.0,
        mode: str = "hold",
        start_s: float = 0.0,
        end_s: float | None = None,
        max_gap_s: float = MAX_GAP_S,
    ):
        if not fps > 0:
            raise ValueError(f"PlaybackClock: fps must be > 0, got {fps}")
        if not speed > 0:
            raise ValueError(f"PlaybackClock: speed must be > 0, got {speed}")
        if mode not in ("hold", "nearest"):
            raise ValueError(f"PlaybackClock: mode must be 'hold' or 'nearest', got {mode!r}")
        if not max_gap_s > 0:
            raise ValueError(f"PlaybackClock: max_gap_s must be > 0, got {max_gap_s}")
        if start_s < 0 or (end_s is not None and end_s < start_s):
            raise ValueError(f"PlaybackClock: bad span start_s={start_s}, end_s={end_s}")
        self.readings = readings
        self.fps = float(fps)
        self.speed = float(speed)
        self.mode = mode
        self.start_s = float(start_s)
        self.end_s = end_s
        self.max_gap_ns = int(round(max_gap_s * 1e9))
        self.cuts: list[tuple[int, int]] = []
        self._step_ns = self.speed * 1e9 / self.fps

    def _offset_ns(self, i: int) -> int:
        return int(round(self.start_s * 1e9 + i * self._step_ns))

    def frame_count(self, duration_ns: int) -> int:
        """Frames produced for a take whose readings span duration_ns (last minus first)."""
        end_ns = duration_ns if self.end_s is None else min(duration_ns, int(round(self.end_s * 1e9)))
        start_ns = int(round(self.start_s * 1e9))
        if end_ns < start_ns:
            return 0
        n = int((end_ns - start_ns) // self._step_ns) + 1
        while self._offset_ns(n) <= end_ns:  # guard the float division at the boundary
            n += 1
        while n > 0 and self._offset_ns(n - 1) > end_ns:
            n -= 1
        return n

    def __len__(self) -> int:
        times = getattr(self.readings, "timestamps", None)
        if times is not None:
            t = times()
            return 0 if len(t) == 0 else self.frame_count(capped_duration_ns(t, self.max_gap_ns))
        first = getattr(self.readings, "t_first_ns", None)
        last = getattr(self.readings, "t_last_ns", None)
        if first is None or last is None:
            if hasattr(self.readings, "t_first_ns"):
                return 0
            raise TypeError("PlaybackClock: len() needs a TakeReader (with t_first_ns, t_last_ns)")
        return self.frame_count(last - first)

    def _advance(self, cur: Reading, cur_p: int, nxt: Reading | None) -> int:
        """Play time (ns from the first reading) of nxt, which follows cur at play time cur_p."""
        if nxt is None:
            return cur_p
        gap = nxt.t_ns - cur.t_ns
        if gap > self.max_gap_ns:
            self.cuts.append((cur.t_ns, gap))
            gap = self.max_gap_ns
        return cur_p + gap

    def __iter__(self) -> Iterator[PlaybackFrame]:
        it = iter(self.readings)
        cur = next(it, None)
        if cur is None:
            return
        cur_p = 0
        nxt = next(it, None)
        nxt_p = self._advance(cur, cur_p, nxt)
        end_ns = None if self.end_s is None else int(round(self.end_s * 1e9))
        i = 0
        while True:
            pt = self._offset_ns(i)
            if end_ns is not None and pt > end_ns:
                return
            while nxt is not None and nxt_p <= pt:
                cur, cur_p = nxt, nxt_p
                nxt = next(it, None)
                nxt_p = self._advance(cur, cur_p, nxt)
            if nxt is None and pt > cur_p:
                return
            shown = cur
            if self.mode == "nearest" and nxt is not None and nxt_p - pt < pt - cur_p:
                shown = nxt
            yield PlaybackFrame(i, i / self.fps, cur.t_ns + (pt - cur_p), shown)
            i += 1


def capped_duration_ns(t_ns: np.ndarray, max_gap_ns: int) -> int:
    """Play time of readings at t_ns ((N,) int64, in order) with every gap cut to max_gap_ns."""
    return int(np.minimum(np.diff(np.asarray(t_ns, dtype=np.int64)), max_gap_ns).sum())


def pace(
    frames: Iterable[PlaybackFrame],
    *,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[PlaybackFrame]:
    """Yield frames no earlier than their t_s after the first one, for real-time display.

    Frames are never dropped here; a consumer that falls behind sees them late.
    clock: seconds, monotonic; sleep: seconds. Both injectable for tests.
    """
    start = None
    for frame in frames:
        if start is None:
            start = clock()
        wait = start + frame.t_s - clock()
        if wait > 0:
            sleep(wait)
        yield frame
