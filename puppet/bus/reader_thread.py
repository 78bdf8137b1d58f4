"""A thread that reads the bus at a steady rate, independent of its consumers.

Readings go into a bounded newest-wins queue: a slow consumer never slows the reader and always
gets the newest reading; the oldest readings are dropped first (and counted).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future

from puppet.bus.errors import BusError
from puppet.bus.reader import ServoReader
from puppet.errors import PuppetError
from puppet.reading import Reading


class ReaderDied(PuppetError, RuntimeError):
    """The reader thread stopped on an unexpected error (a bug, not a bus fault); see __cause__."""


class LatestQueue:
    """Bounded FIFO of readings where a full queue drops its oldest entry.

    maxlen: capacity (>= 1). ``latest()`` returns the newest entry and empties the queue;
    ``drain()`` returns every entry, oldest first. ``dropped`` counts entries never handed out.
    """

    def __init__(self, maxlen: int = 8):
        if maxlen < 1:
            raise ValueError(f"LatestQueue: maxlen {maxlen} must be >= 1")
        self._items: deque = deque(maxlen=maxlen)
        self._cond = threading.Condition()
        self.dropped = 0
        self.pushed = 0

    def put(self, item) -> None:
        with self._cond:
            if len(self._items) == self._items.maxlen:
                self.dropped += 1
            self._items.append(item)
            self.pushed += 1
            self._cond.notify_all()

    def latest(self, timeout: float | None = None):
        """The newest entry (waiting up to ``timeout`` s for one); None if none came. Older
        entries still queued are discarded (counted in ``dropped``)."""
        with self._cond:
            if not self._items and not self._cond.wait_for(lambda: bool(self._items), timeout):
                return None
            item = self._items.pop()
            self.dropped += len(self._items)
            self._items.clear()
            return item

    def drain(self) -> list:
        """Every queued entry, oldest first (for a recorder that wants them all)."""
        with self._cond:
            out = list(self._items)
            self._items.clear()
            return out

    def __len__(self) -> int:
        return len(self._items)


class ReaderThread:
    """Runs ``reader.read()`` at ``rate_hz`` (None: back to back) on a daemon thread.

    Consumers call ``latest()`` (newest reading) or ``drain()``; other threads run bus
    commands on the reader thread with ``call(fn, *args)`` (-> Future). It drives nothing:
    servos that move are driven through ReaderProcess's cycle hook (puppet.drive).

    stats: reads, overruns (a period missed: the read took longer than 1/rate), dropped.
    """

    def __init__(self, reader: ServoReader, rate_hz: float | None = 500.0, queue_len: int = 8):
        if rate_hz is not None and rate_hz <= 0:
            raise ValueError(f"ReaderThread: rate_hz {rate_hz} must be > 0 (or None)")
        self.reader = reader
        self.period_ns = int(1e9 / rate_hz) if rate_hz else 0
        self.queue = LatestQueue(queue_len)
        self._stop = threading.Event()
        self._calls: deque = deque()
        self._thread: threading.Thread | None = None
        self.failure: BaseException | None = None
        self.reads = 0
        self.overruns = 0
        self.bus_errors = 0

    # ---- lifetime ------------------------------------------------------------------------
    def start(self) -> ReaderThread:
        if self._thread is not None:
            raise RuntimeError("ReaderThread: already started")
        self._thread = threading.Thread(target=self._run, name="puppet-bus-reader", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def __enter__(self) -> ReaderThread:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def log(self):
        """The reader's EventLog of bus events (same attribute as ReaderProcess.log)."""
        return self.reader.log

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ---- consumer side -------------------------------------------------------------------
    def latest(self, timeout: float | None = 1.0) -> Reading | None:
        """The newest reading (waits up to ``timeout`` s). ReaderDied if the thread died."""
        self._check()
        return self.queue.latest(timeout)

    def drain(self) -> list[Reading]:
        self._check()
        return self.queue.drain()

    def call(self, fn: Callable, *args, **kwargs) -> Future:
        """Run ``fn(*args, **kwargs)`` on the reader thread between two reads."""
        self._check()
        future: Future = Future()
        self._calls.append((future, fn, args, kwargs))
        return future

    def _check(self) -> None:
        if self.failure is not None:
            raise ReaderDied("the bus reader thread stopped") from self.failure

    # ---- the loop ------------------------------------------------------------------------
    def _run(self) -> None:
        next_ns = time.monotonic_ns()
        try:
            while not self._stop.is_set():
                self._run_calls()
                try:
                    reading = self.reader.read()
                except BusError as exc:  # read() absorbs bus faults; this is a safety net
                    self.bus_errors += 1
                    self.reader.log.add("read_error", (), str(exc))
                else:
                    self.queue.put(reading)
                    self.reads += 1
                if self.period_ns:
                    next_ns += self.period_ns
                    now = time.monotonic_ns()
                    if now > next_ns:
                        self.overruns += 1
                        next_ns = now  # do not burst to catch up
                    else:
                        self._stop.wait((next_ns - now) / 1e9)
        except BaseException as exc:
            self.failure = exc
            with self.queue._cond:
                self.queue._cond.notify_all()
            raise

    def _run_calls(self) -> None:
        while self._calls:
            future, fn, args, kwargs = self._calls.popleft()
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn(*args, **kwargs))
            except Exception as exc:  # handed to the caller through the Future, not swallowed
                future.set_exception(exc)
