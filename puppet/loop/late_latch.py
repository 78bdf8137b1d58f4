"""LateLatch: each frame starts from as young a reading as the loop can get."""

from __future__ import annotations

import time
from collections.abc import Callable


class LateLatch:
    """Late latching: each frame starts from as young a reading as the loop can get.

    With a source that reads on request (``request_reading()``: ReaderProcess), the loop asks
    for a reading just before its readback (``request``), about one bus transaction before the
    next frame starts, and that frame waits for it (at most one period, ``top_up``): the reading
    is then about one transaction old instead of up to a period older. With other sources, when
    the loop has time to spare at ``min_fps``, it waits briefly for a reading newer than the
    newest in hand (lower reading-to-frame latency, at the cost of the spare time).

    min_fps: the frame rate to keep; period_s: the source's period between readings. Without a
    request it waits only when a frame's own work (a running mean of solve..sinks) plus one
    period still fits in 1 / min_fps and the newest reading is older than half a period; it
    waits one period at most.
    """

    def __init__(self, min_fps: float, period_s: float):
        self.budget_s = 1.0 / min_fps
        self.period_s = period_s
        self.work_s = self.budget_s  # no spare time assumed until frames have been measured
        self.requested_ns = 0  # when the pending request was made (0: none)

    def note_work(self, seconds: float) -> None:
        self.work_s += 0.1 * (seconds - self.work_s)

    def request(self, source) -> None:
        """Ask ``source`` for a reading now, if it reads on request (else nothing)."""
        ask = getattr(source, "request_reading", None)
        if ask is not None:
            self.requested_ns = time.monotonic_ns()
            ask()

    def top_up(self, source, batch: list) -> list:
        """``batch`` plus any readings that came while waiting for a fresher one."""
        if self.requested_ns:
            requested_ns, self.requested_ns = self.requested_ns, 0
            return self._wait(source, batch, lambda newest: newest.t_ns >= requested_ns,
                              requested_ns / 1e9 + self.period_s)
        if self.work_s + self.period_s > self.budget_s:
            return batch
        age_s = (time.monotonic_ns() - batch[-1].t_ns) / 1e9
        if age_s < 0.5 * self.period_s:
            return batch
        held_ns = batch[-1].t_ns
        return self._wait(source, batch, lambda newest: newest.t_ns > held_ns,
                          time.monotonic_ns() / 1e9 + self.period_s)

    @staticmethod
    def _wait(source, batch: list, fresh: Callable, deadline_s: float) -> list:
        """``batch`` plus what comes until the newest reading is ``fresh`` or ``deadline_s``
        (monotonic seconds) passes."""
        while not fresh(batch[-1]) and time.monotonic_ns() / 1e9 < deadline_s:
            newer = source.drain()
            if newer:
                batch = batch + newer
            else:
                time.sleep(0.0002)
        return batch
