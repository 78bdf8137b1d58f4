"""PlaybackClock: turns a take's timestamped readings into frames at a fixed output rate."""

from __future__ import annotations

import time
from typing import Callable, Iterable, Iterator, NamedTuple

from puppet.bus.reading import Reading


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

    readings: iterable of Reading in time order (a TakeReader, or its readings()).
    fps:      output frames per second.
    speed:    take seconds per output second (> 0).
    mode:     "hold": the latest reading at or before the frame's take time (sample and hold);
              "nearest": the reading nearest in time (ties go to the earlier one).
    start_s, end_s: take time span to play, seconds from the first reading (end_s None: to
              the last reading).
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
    ):
        if not fps > 0:
            raise ValueError(f"PlaybackClock: fps must be > 0, got {fps}")
        if not speed > 0:
            raise ValueError(f"PlaybackClock: speed must be > 0, got {speed}")
        if mode not in ("hold", "nearest"):
            raise ValueError(f"PlaybackClock: mode must be 'hold' or 'nearest', got {mode!r}")
        if start_s < 0 or (end_s is not None and end_s < start_s):
            raise ValueError(f"PlaybackClock: bad span start_s={start_s}, end_s={end_s}")
        self.readings = readings
        self.fps = float(fps)
        self.speed = float(speed)
        self.mode = mode
        self.start_s = float(start_s)
        self.end_s = end_s
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
        first = getattr(self.readings, "t_first_ns", None)
        last = getattr(self.readings, "t_last_ns", None)
        if first is None or last is None:
            if hasattr(self.readings, "t_first_ns"):
                return 0
            raise TypeError("PlaybackClock: len() needs a TakeReader (with t_first_ns, t_last_ns)")
        return self.frame_count(last - first)

    def __iter__(self) -> Iterator[PlaybackFrame]:
        it = iter(self.readings)
        cur = next(it, None)
        if cur is None:
            return
        t0 = cur.t_ns
        nxt = next(it, None)
        end_ns = None if self.end_s is None else t0 + int(round(self.end_s * 1e9))
        i = 0
        while True:
            tt = t0 + self._offset_ns(i)
            if end_ns is not None and tt > end_ns:
                return
            while nxt is not None and nxt.t_ns <= tt:
                cur = nxt
                nxt = next(it, None)
            if nxt is None and tt > cur.t_ns:
                return
            shown = cur
            if self.mode == "nearest" and nxt is not None and nxt.t_ns - tt < tt - cur.t_ns:
                shown = nxt
            yield PlaybackFrame(i, i / self.fps, tt, shown)
            i += 1


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
