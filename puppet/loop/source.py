"""The reading-source interface the run loops depend on (a bus reader process or thread, a
take played on the wall clock, the rest pose for handles only)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from puppet.reading import Reading


@runtime_checkable
class ReadingSource(Protocol):
    """What ``run_live`` needs of a source.

    drain():          every reading that came since the last call, oldest first (may be []).
    latest(timeout):  the newest reading, waiting up to ``timeout`` seconds; None if none came.
    log:              an EventLog of bus events (``.counts``: {kind: count}; empty for no bus).
    Optional: ``rate_hz`` (readings per second, for late latching) and ``request_reading()``
    (read now, for a source that reads on request; see puppet.loop.late_latch).
    """

    log: object

    def drain(self) -> list[Reading]: ...

    def latest(self, timeout: float | None = ...) -> Reading | None: ...
