"""ReaderProcess: a ServoReader running in its own process, readings shared through a ring.

Why a process: moderngl keeps the GIL while llvmpipe renders a frame (tens of ms), and the SDK
busy-polls under the GIL; a reader thread in the rendering process would stall (and its reads
time out) during every draw. In a process of its own the bus keeps its rate whatever the
consumer does.

Shared ring (multiprocessing shared memory, ``slots`` entries, written only by the child):
    t_ns (slots,) int64, ticks (slots, k) int32, ok (slots, k) bool, written (1,) int64.
The child fills slot ``written % slots`` and then increments ``written``; the consumer copies
the slots it has not seen and re-checks ``written`` to drop any slot overwritten meanwhile.
Setup report, bus events and errors come back over a pipe; commands (goals, reboot, stop) go
down another.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from collections.abc import Mapping
from multiprocessing import shared_memory

import numpy as np

from puppet.bus.health import EventLog
from puppet.bus.reading import Reading
from puppet.errors import PuppetError


class ReaderProcessError(PuppetError, RuntimeError):
    """The reader process could not start or stopped on an error (message from the child)."""


def _ring_arrays(buf, slots: int, k: int):
    t_ns = np.ndarray((slots,), np.int64, buf, 0)
    offset = 8 * slots
    ticks = np.ndarray((slots, k), np.int32, buf, offset)
    offset += 4 * slots * k
    ok = np.ndarray((slots, k), np.bool_, buf, offset)
    offset += slots * k
    offset += (-offset) % 8
    written = np.ndarray((1,), np.int64, buf, offset)
    stop = np.ndarray((1,), np.int64, buf, offset + 8)
    return t_ns, ticks, ok, written, stop


def _ring_size(slots: int, k: int) -> int:
    size = 8 * slots + 4 * slots * k + slots * k
    return size + (-size) % 8 + 16


def _child(shm_name, slots, port, servos, options, rate_hz, events, commands):
    """The reader process: open the bus, then read at rate_hz into the ring until the ring's
    stop word is set (a plain shared word, no lock: a child killed at any moment cannot leave
    the parent blocked on a lock it held)."""
    from puppet.bus.errors import BusError
    from puppet.bus.reader import ServoReader

    shm = shared_memory.SharedMemory(name=shm_name)
    try:
        t_ns, ticks, ok, written, stop = _ring_arrays(shm.buf, slots, len(servos))
        reader = ServoReader(port, servos, **options)
        try:
            report = reader.open()
        except (BusError, ValueError) as exc:
            events.send(("error", f"{type(exc).__name__}: {exc}"))
            return
        events.send(("report", report))
        period_ns = int(1e9 / rate_hz) if rate_hz else 0
        next_ns = time.monotonic_ns()
        while not stop[0]:
            while commands.poll():
                try:
                    name, arg = commands.recv()
                except (EOFError, OSError):  # the parent is gone: nobody to read for
                    name, arg = "stop", None
                    stop[0] = 1
                    break
                if name == "goals":
                    reader.write_goals(arg)
                elif name == "reboot":
                    reader.reboot(arg)
            reading = reader.read()
            slot = int(written[0]) % slots
            t_ns[slot] = reading.t_ns
            ticks[slot] = reading.ticks
            ok[slot] = reading.ok
            written[0] += 1
            for event in reader.log.drain():
                events.send(("event", event))
            if period_ns:
                next_ns += period_ns
                now = time.monotonic_ns()
                if now > next_ns:
                    next_ns = now  # an overrun: do not burst to catch up
                else:
                    commands.poll((next_ns - now) / 1e9)  # a command (stop) ends the wait
        reader.close()
    finally:
        del t_ns, ticks, ok, written, stop
        shm.close()


class ReaderProcess:
    """Reads servos at ``rate_hz`` in a child process; same consumer API as ReaderThread.

    port:    port name (the child opens it).
    servos:  {id: model name}, reading order.
    slots:   readings the ring holds (a consumer that falls further behind loses the oldest).
    options: passed to ``ServoReader`` in the child (baud, latency_ms, read_mode, ...).

    ``start()`` waits for the child's setup and returns its SetupReport (``report``), or raises
    ReaderProcessError with the child's message. ``drain()`` gives every new reading, oldest
    first; ``latest(timeout)`` the newest. ``log`` mirrors the child's bus events.
    """

    def __init__(self, port: str, servos: Mapping[int, str], *, rate_hz: float = 500.0,
                 slots: int = 4096, **options):
        self.port = str(port)
        self.servos = {int(i): str(m) for i, m in servos.items()}
        self.ids = np.array(list(self.servos), np.int64)
        self.rate_hz = rate_hz
        self.slots = int(slots)
        self.options = options
        self.log = EventLog()
        self.report = None
        self.dropped = 0
        self._read = 0
        self._ctx = mp.get_context("spawn")
        self._shm = None
        self._proc = None

    def start(self, timeout_s: float = 30.0):
        k = len(self.servos)
        self._shm = shared_memory.SharedMemory(create=True, size=_ring_size(self.slots, k))
        self._t_ns, self._ticks, self._ok, self._written, self._stop_word = _ring_arrays(
            self._shm.buf, self.slots, k)
        self._written[0] = 0
        self._stop_word[0] = 0
        self._events, child_events = self._ctx.Pipe(duplex=False)
        self._events_closed = False
        child_commands, self._commands = self._ctx.Pipe(duplex=False)
        self._proc = self._ctx.Process(
            target=_child, name="puppet-bus-reader", daemon=True,
            args=(self._shm.name, self.slots, self.port, self.servos, self.options, self.rate_hz,
                  child_events, child_commands))
        self._proc.start()
        # The child has its own copies now: with ours closed, its death is an end of file here
        # (a message cut by it raises instead of blocking a read forever).
        child_events.close()
        child_commands.close()
        deadline = time.monotonic() + timeout_s
        while self.report is None:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self._events_closed or not self._proc.is_alive() and not self._events.poll():
                self.stop()
                raise ReaderProcessError(f"{self.port}: the reader process did not start")
            if self._events.poll(min(remaining, 0.1)):
                self._take_message()
        return self.report

    def _take_message(self) -> None:
        try:
            kind, payload = self._events.recv()
        except (EOFError, OSError):
            self._events_closed = True  # the child is gone: its end of the pipe closed
            return
        if kind == "report":
            self.report = payload
        elif kind == "event":
            self.log.events.append(payload)
            self.log.counts[payload.kind] = self.log.counts.get(payload.kind, 0) + 1
        elif kind == "error":
            self.stop()
            raise ReaderProcessError(f"{self.port}: {payload}")

    def _poll_events(self) -> None:
        while not self._events_closed and self._events.poll():
            self._take_message()

    @property
    def produced(self) -> int:
        """Readings the child has written so far (consumed or not)."""
        return int(self._written[0]) if self._shm is not None else self._read

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.is_alive()

    def drain(self) -> list[Reading]:
        """Every reading since the last call, oldest first."""
        self._poll_events()
        written = int(self._written[0])
        first = max(self._read, written - self.slots + 1)
        self.dropped += first - self._read
        out = []
        for n in range(first, written):
            slot = n % self.slots
            out.append(Reading(int(self._t_ns[slot]), self.ids, self._ticks[slot].copy(),
                               self._ok[slot].copy()))
        if int(self._written[0]) - first > self.slots - 1:  # overwritten while copying
            lost = int(self._written[0]) - self.slots + 1 - first
            out = out[lost:]
            self.dropped += lost
        self._read = written
        if not out and not self.alive:
            raise ReaderProcessError(f"{self.port}: the reader process stopped")
        return out

    def latest(self, timeout: float | None = 1.0) -> Reading | None:
        """The newest reading (waiting up to ``timeout`` s for a new one); None if none came."""
        deadline = time.monotonic() + (timeout or 0.0)
        while True:
            batch = self.drain()
            if batch:
                return batch[-1]
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.0005)

    def set_goals(self, goals: Mapping[int, int]) -> None:
        """Goal positions (continuous ticks) for the reader's actuators."""
        self._commands.send(("goals", {int(i): int(t) for i, t in goals.items()}))

    def reboot(self, dxl_id: int) -> None:
        self._commands.send(("reboot", int(dxl_id)))

    def stop(self, timeout: float = 3.0) -> None:
        if self._proc is not None:
            self._stop_word[0] = 1
            try:
                self._commands.send(("stop", None))   # wakes a child pacing its reads
            except (OSError, ValueError):
                pass  # the child is gone already: its end of the pipe is closed
            self._proc.join(timeout)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join()
            self._proc = None
        if self._shm is not None:
            del self._t_ns, self._ticks, self._ok, self._written, self._stop_word
            self._shm.close()
            self._shm.unlink()
            self._shm = None

    def __enter__(self) -> ReaderProcess:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
