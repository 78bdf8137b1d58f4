"""BackgroundTakeWriter: a TakeWriter on its own thread, so the bus thread never waits on disk."""

from __future__ import annotations

import queue
import threading
from typing import NamedTuple

from puppet.reading import Reading
from puppet.take.errors import TakeError
from puppet.take.writer import TakeWriter

_STOP = object()


class _Mark(NamedTuple):
    t_ns: int
    name: str


class BackgroundTakeWriter:
    """Queues readings for a TakeWriter that runs on a daemon thread.

    write() copies the reading's arrays (the caller may reuse its buffers) and returns at once;
    a reading reaches the file within microseconds to a few milliseconds (fsync included), well
    inside the 100 ms crash-safety promise. An error of the writer thread (a full disk, or any
    unexpected error) is raised as TakeError naming the take by the next write() or by close();
    readings queued after it are dropped (the thread keeps draining the queue, so nothing
    waits on a dead thread), and every reading written before it stays readable.

    writer:    an open TakeWriter, owned from now on (closed by close()).
    max_queue: readings that may wait; when full, write() raises TakeError rather than block.
    dropped:   readings refused because the queue was full.
    """

    def __init__(self, writer: TakeWriter, *, max_queue: int = 10_000):
        self.writer = writer
        self.path = writer.path
        self.dropped = 0
        self._queue: queue.Queue = queue.Queue(maxsize=max_queue)
        self._error: BaseException | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"take-writer {self.path.name}",
                                        daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            if self._error is None:
                try:
                    if isinstance(item, _Mark):
                        self.writer.mark(item.t_ns, item.name)
                        continue
                    self.writer.write(item)
                except BaseException as e:  # noqa: BLE001 - kept and raised in the caller's thread
                    self._error = e

    def _raise_error(self) -> None:
        if self._error is not None:
            e = self._error
            if isinstance(e, TakeError):
                raise TakeError(self.path, f"take writer thread failed: {e.reason}") from e
            raise TakeError(self.path, f"take writer thread failed: {type(e).__name__}: {e}; "
                            f"the {self.writer.count} readings written before it are kept") from e

    def write(self, reading: Reading) -> None:
        """Queue one reading (arrays copied). Never blocks on disk."""
        if self._closed:
            raise TakeError(self.path, "write() after close()")
        self._raise_error()
        copy = Reading(t_ns=reading.t_ns, ids=reading.ids, ticks=reading.ticks.copy(),
                       ok=reading.ok.copy(),
                       late=None if reading.late is None else reading.late.copy())
        try:
            self._queue.put_nowait(copy)
        except queue.Full:
            self.dropped += 1
            raise TakeError(
                self.path, f"take writer queue is full ({self._queue.maxsize} readings): "
                "the disk cannot keep up"
            ) from None

    def mark(self, t_ns: int, name: str) -> None:
        """Queue a named time mark (TakeWriter.mark), in order with the readings."""
        if self._closed:
            raise TakeError(self.path, "mark() after close()")
        self._raise_error()
        self._queue.put(_Mark(int(t_ns), str(name)))

    def close(self) -> None:
        """Write everything queued, close the take, and raise the writer thread's error if any."""
        if self._closed:
            return
        self._closed = True
        stopped = False
        while self._thread.is_alive():  # a dead thread takes nothing from a full queue
            try:
                self._queue.put(_STOP, timeout=0.1)
                stopped = True
                break
            except queue.Full:
                continue
        self._thread.join()
        try:
            self._raise_error()
            if not stopped:
                raise TakeError(self.path, "take writer thread ended unexpectedly; the "
                                f"{self.writer.count} readings written before are kept")
        finally:
            self.writer.close()

    def __enter__(self) -> "BackgroundTakeWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
