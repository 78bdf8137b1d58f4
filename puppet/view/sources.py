"""Reading sources for the view-only modes, with the loop's source interface
(``drain()``, ``latest(timeout)``, ``log``), so ``run_live`` runs them like a bus reader.

RestSource: no bus at all: the rig's zero ticks (its rest pose) at a steady rate; the pose then
comes only from the view's dragged handles (``puppet view``).
TakeSource: a take played on the wall clock with pause, seek and speed from the page
(``puppet play TAKE --view``); the reading at its play position is the take's one rule's
(``puppet.take.Playback.at``: ticks interpolated, long gaps cut), stamped with the time it is shown.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from puppet.events import EventLog
from puppet.reading import Reading


#: A play position this close to a take's end (s) is its end: play() starts over (a slider's
#: value is rounded, so scrubbing to the end may stop a hair short of it).
END_S = 0.01


class _PacedSource:
    """A source that makes its own readings, one every ``period_s`` seconds (monotonic clock).

    ids: (k,) servo ids of every reading; rate_hz: readings per second. A subclass defines
    _reading() -> Reading, the reading to hand out now. drain() has nothing queued; log is
    an empty EventLog (no bus, no bus events).
    """

    def __init__(self, ids, rate_hz: float):
        self.ids = np.asarray(ids)
        self.period_s = 1.0 / rate_hz
        self.log = EventLog()
        self._next = time.monotonic()

    def _reading(self) -> Reading:
        raise NotImplementedError

    def drain(self) -> list[Reading]:
        return []

    def latest(self, timeout: float | None = 1.0) -> Reading | None:
        """The next reading, once its time has come; None (after waiting timeout seconds,
        None = 0) when it is due later than that. A late reading is not made up for."""
        now = time.monotonic()
        wait = self._next - now
        if wait > (timeout or 0.0):
            time.sleep(timeout or 0.0)
            return None
        if wait > 0:
            time.sleep(wait)
        self._next = max(self._next + self.period_s, time.monotonic())
        return self._reading()


class RestSource(_PacedSource):
    """The rig's rest pose (zero ticks, every servo ok) at ``rate_hz`` readings per second."""

    def __init__(self, ids: np.ndarray, zero_ticks: np.ndarray, rate_hz: float = 60.0):
        super().__init__(ids, rate_hz)
        self._ticks = np.asarray(np.round(zero_ticks), np.int32)
        self._ok = np.ones(len(self.ids), bool)

    def _reading(self) -> Reading:
        return Reading(time.monotonic_ns(), self.ids, self._ticks, self._ok)


class TakeSource(_PacedSource):
    """A take played on the wall clock at ``rate_hz`` frames per second.

    frames: the take's Playback (puppet.take); positions are its play time (seconds from the
    first reading, long gaps cut), markers (seconds, name) too. Controls (any thread): pause(),
    play(), seek(seconds), set_speed(factor). At the end it holds the last reading (paused).
    """

    def __init__(self, frames, *, speed: float = 1.0, rate_hz: float = 60.0, markers=()):
        super().__init__(frames.ids, rate_hz)
        self._frames = frames
        self.duration_s = frames.duration_s
        self.speed = float(speed)
        self.paused = False
        self.markers = list(markers)
        self._lock = threading.Lock()
        self._position_s = 0.0
        self._last = self._next  # play time starts now, with the first reading

    @property
    def position_s(self) -> float:
        return self._position_s

    def pause(self) -> None:
        with self._lock:
            self._advance()
            self.paused = True

    def play(self) -> None:
        with self._lock:
            self._advance()
            if self._position_s >= self.duration_s - END_S:  # at the end (scrubbed there): from the start
                self._position_s = 0.0
            self.paused = False

    def seek(self, seconds: float) -> None:
        with self._lock:
            self._advance()
            self._position_s = float(np.clip(seconds, 0.0, self.duration_s))

    def set_speed(self, factor: float) -> None:
        with self._lock:
            self._advance()
            self.speed = float(np.clip(factor, 0.05, 8.0))

    def _advance(self) -> None:
        now = time.monotonic()
        if not self.paused:
            self._position_s += (now - self._last) * self.speed
            if self._position_s >= self.duration_s:
                self._position_s = self.duration_s
                self.paused = True
        self._last = now

    def _reading(self) -> Reading:
        """The take at the play position (advanced to now), stamped now."""
        with self._lock:
            self._advance()
            position = self._position_s
        shown = self._frames.at(position)
        return Reading(time.monotonic_ns(), self.ids, shown.ticks, shown.ok, shown.rotations)

    def state(self) -> dict:
        return {"position_s": round(self._position_s, 3), "duration_s": round(self.duration_s, 3),
                "paused": self.paused, "speed": self.speed,
                "markers": [{"t_s": round(t, 3), "name": n} for t, n in self.markers]}
