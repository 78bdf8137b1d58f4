"""ReaderProcess: a ServoReader running in its own process, readings shared through a ring.

Why a process: moderngl keeps the GIL while llvmpipe renders a frame (tens of ms), and the SDK
busy-polls under the GIL; a reader thread in the rendering process would stall (and its reads
time out) during every draw. In a process of its own the bus keeps its rate whatever the
consumer does.

Shared ring (multiprocessing shared memory, ``slots`` entries, written only by the child):
    t_ns (slots,) int64, ticks (slots, k) int32, ok (slots, k) bool, late (slots, k) bool
    (``Reading.late``: held only because the reply came late, not a fault), written (1,) int64.
The child fills slot ``written % slots`` and then increments ``written``; the consumer copies
the slots it has not seen and re-checks ``written`` to drop any slot overwritten meanwhile.
Setup report, bus events and errors come back over a pipe; commands (read now, stop) go down
another.

Cycle hook (``hook``: an object of the ``CycleHook`` shape, made by whoever drives servos; the
bus only calls it; puppet.drive.actuators plugs the rig's actuators in here): the hook's ``ids``
are the reader's ``driven`` servos (their torque is never changed nor are they rebooted by the
reader). In the child ``start(reader, note)`` runs after the reader's setup, ``before_read(reader,
goals)`` once per cycle just before the read, and ``stop()`` on every way out of the loop (stop,
SIGTERM, its parent gone, an exception); its result (torque read back) comes back as
``torque_after``. If the child dies without that, the parent calls ``stop_from_parent``.

Goal channel (only with a hook), a second shared block written only by the consumer: seq (1,)
int64, src_t_ns (1,) int64, goals (a,) float64. The consumer makes seq odd, writes, makes it even
(a seqlock); the child copies the goals when seq is even and new and hands the newest to
``before_read`` each cycle. For each new goal vector it notes (src_t_ns, bus_t_ns) in a small
ring (``goal_delays_ms``): the sensor reading the goals were solved from, and when the hook had
written them.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import time
from collections.abc import Callable, Mapping
from multiprocessing import shared_memory
from typing import Protocol

import numpy as np

from puppet.child_signals import children_deaf_to_ctrl_c
from puppet.errors import PuppetError
from puppet.events import EventLog
from puppet.reading import Reading


class ReaderProcessError(PuppetError, RuntimeError):
    """The reader process could not start or stopped on an error (message from the child)."""


class CycleHook(Protocol):
    """What a ReaderProcess calls in its child each bus cycle (picklable: it travels to the
    child). ``ids``: (a,) the servos it drives, which the reader leaves alone (``driven``)."""

    ids: tuple[int, ...]

    def start(self, reader, note: Callable[[str], None]) -> list:
        """After the reader's setup: take over ``ids`` on ``reader.link`` -> setup Changes.
        A PuppetError or BusError refuses (the reader process then fails to start)."""

    def before_read(self, reader, goals: np.ndarray) -> None:
        """Once per cycle before the read; ``goals`` (a,) the consumer's newest (NaN until the
        first). Bus faults are the hook's to handle (``reader.log`` takes its events)."""

    def stop(self) -> dict | None:
        """On every way out of the child's loop: {id: Torque Enable read back}, or None when
        there was nothing to stop."""

    def stop_from_parent(self, port: str, options: dict, note: Callable[[str], None]) -> dict | None:
        """The child died without ``stop``: do it from the parent on ``port`` (``options``:
        the reader's, baud and latency_ms among them)."""


def _ring_arrays(buf, slots: int, k: int):
    t_ns = np.ndarray((slots,), np.int64, buf, 0)
    offset = 8 * slots
    ticks = np.ndarray((slots, k), np.int32, buf, offset)
    offset += 4 * slots * k
    ok = np.ndarray((slots, k), np.bool_, buf, offset)
    offset += slots * k
    late = np.ndarray((slots, k), np.bool_, buf, offset)
    offset += slots * k
    offset += (-offset) % 8
    written = np.ndarray((1,), np.int64, buf, offset)
    stop = np.ndarray((1,), np.int64, buf, offset + 8)
    return t_ns, ticks, ok, late, written, stop


def _ring_size(slots: int, k: int) -> int:
    size = 8 * slots + 4 * slots * k + 2 * slots * k
    return size + (-size) % 8 + 16


DELAY_SLOTS = 4096
"""(source reading, goal on the bus) time pairs the goal channel keeps (the newest)."""


def _goal_arrays(buf, a: int):
    seq = np.ndarray((1,), np.int64, buf, 0)
    src_t_ns = np.ndarray((1,), np.int64, buf, 8)
    goals = np.ndarray((a,), np.float64, buf, 16)
    offset = 16 + 8 * a
    delay_src = np.ndarray((DELAY_SLOTS,), np.int64, buf, offset)
    delay_bus = np.ndarray((DELAY_SLOTS,), np.int64, buf, offset + 8 * DELAY_SLOTS)
    delay_n = np.ndarray((1,), np.int64, buf, offset + 16 * DELAY_SLOTS)
    return seq, src_t_ns, goals, delay_src, delay_bus, delay_n


def _goal_size(a: int) -> int:
    return 16 + 8 * a + 16 * DELAY_SLOTS + 8


class _GoalInbox:
    """The child's side of the goal channel: the newest consistent goals, once each."""

    def __init__(self, buf, a: int) -> None:
        (self.seq, self.src_t_ns, self.goals, self.delay_src, self.delay_bus,
         self.delay_n) = _goal_arrays(buf, a)
        self.seen = 0
        self.wanted = np.full(a, np.nan)
        self.src = 0

    def take(self) -> bool:
        """Copy new goals into ``wanted`` (and their reading's time into ``src``); False if none."""
        first = int(self.seq[0])
        if first == self.seen or first % 2:
            return False
        self.wanted[:] = self.goals
        src = int(self.src_t_ns[0])
        if int(self.seq[0]) != first:  # rewritten while copying: take it next cycle
            return False
        self.seen, self.src = first, src
        return True

    def note(self, bus_t_ns: int) -> None:
        n = int(self.delay_n[0])
        self.delay_src[n % DELAY_SLOTS] = self.src
        self.delay_bus[n % DELAY_SLOTS] = bus_t_ns
        self.delay_n[0] = n + 1


def _stop_hook(hook, events) -> None:
    """Stop the hook (if started) and tell the parent what reads back."""
    if hook is None:
        return
    after = hook.stop()
    if after is None:
        return
    try:
        events.send(("torque_off", after))
    except OSError:  # the parent is gone: there is nobody to tell
        return


def _child(shm_name, slots, port, servos, options, rate_hz, events, commands,
           hook=None, goal_shm_name=None):
    """The reader process: open the bus, then read at rate_hz into the ring until the ring's
    stop word is set (a plain shared word, no lock: a child killed at any moment cannot leave
    the parent blocked on a lock it held). With a ``hook``: call it each cycle, and stop it
    on every way out."""
    from puppet.bus.errors import BusError
    from puppet.bus.reader import ServoReader

    shm = shared_memory.SharedMemory(name=shm_name)
    goal_shm = inbox = reader = started = None
    parent = os.getppid()
    # SIGINT is ignored from birth (``children_deaf_to_ctrl_c``): the parent stops us (a
    # terminal's Ctrl-C reaches the whole group); so is SIGTERM to the group (a service manager
    # stopping the command): the parent's stop turns the actuators' torque off here, in order.
    # A parent that dies is noticed (``parent``) and ends us the same way.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    t_ns, ticks, ok, late, written, stop = _ring_arrays(shm.buf, slots, len(servos))
    if hook is not None:
        signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, 1))
    try:
        try:
            # a map or baud its servos cannot do is refused here, as a failed setup
            reader = ServoReader(port, servos, driven=hook.ids if hook is not None else (), **options)
            report = reader.open()
            if hook is not None:
                goal_shm = shared_memory.SharedMemory(name=goal_shm_name)
                inbox = _GoalInbox(goal_shm.buf, len(hook.ids))
                started = hook  # from here on it is stopped on every way out
                report.changes.extend(hook.start(reader, lambda text: events.send(("note", text))))
        except (BusError, PuppetError, ValueError) as exc:
            _stop_hook(started, events)
            started = None
            # a PuppetError's text names its port or servo; a ValueError's gets its type
            events.send(("error", str(exc) if isinstance(exc, PuppetError)
                         else f"{type(exc).__name__}: {exc}"))
            return
        events.send(("report", report))
        period_ns = int(1e9 / rate_hz) if rate_hz else 0
        next_ns = time.monotonic_ns()
        while not stop[0]:
            if hook is not None:
                if os.getppid() != parent:  # the host process is gone
                    break
                new = inbox.take()
                hook.before_read(reader, inbox.wanted)
                if new:
                    inbox.note(time.monotonic_ns())
            while commands.poll():
                try:
                    name, _arg = commands.recv()
                except (EOFError, OSError):  # the parent is gone: nobody to read for
                    name = "stop"
                if name == "stop":
                    stop[0] = 1
                    break
                # "read": the consumer wants a fresh reading now (the wait below ended early)
            reading = reader.read()
            slot = int(written[0]) % slots
            t_ns[slot] = reading.t_ns
            ticks[slot] = reading.ticks
            ok[slot] = reading.ok
            late[slot] = False if reading.late is None else reading.late
            written[0] += 1
            try:
                for event in reader.log.drain():
                    events.send(("event", event))
            except OSError:  # the parent is gone (its end of the pipe closed): stop, hook first
                break
            if period_ns:
                next_ns += period_ns
                now = time.monotonic_ns()
                if now > next_ns:
                    next_ns = now  # an overrun: do not burst to catch up
                elif commands.poll((next_ns - now) / 1e9):  # a command (read, stop) ends the wait
                    next_ns = time.monotonic_ns()  # read now; the schedule goes on from here
    finally:
        _stop_hook(started, events)
        if reader is not None:
            reader.close()
        if inbox is not None:
            del inbox
        if goal_shm is not None:
            goal_shm.close()
        del t_ns, ticks, ok, late, written, stop
        shm.close()


class ReaderProcess:
    """Reads servos at ``rate_hz`` in a child process; same consumer API as ReaderThread.

    port:    port name (the child opens it).
    servos:  {id: model name}, reading order.
    slots:   readings the ring holds (a consumer that falls further behind loses the oldest).
    options: passed to ``ServoReader`` in the child (baud, latency_ms, read_mode, ...).

    hook:    a ``CycleHook`` (e.g. puppet.drive.actuators.ActuatorHook) called in the child each
             cycle with the newest ``set_goals``; ``torque_after`` then holds what its stop read
             back ({id: Torque Enable or None}) and ``notes`` its lines of text.

    ``start()`` waits for the child's setup and returns its SetupReport (``report``), or raises
    ReaderProcessError with the child's message. ``drain()`` gives every new reading, oldest
    first; ``latest(timeout)`` the newest. ``log`` mirrors the child's bus events.
    """

    def __init__(self, port: str, servos: Mapping[int, str], *, rate_hz: float = 500.0,
                 slots: int = 4096, hook: CycleHook | None = None, **options):
        self.port = str(port)
        self.hook = hook
        self.torque_after: dict | None = None
        self.notes: list[str] = []
        self.died: str | None = None   # set by stop(): the child had ended unasked, unexplained
        self._said_error = False
        self._goal_shm = None
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
        (self._t_ns, self._ticks, self._ok, self._late, self._written,
         self._stop_word) = _ring_arrays(self._shm.buf, self.slots, k)
        self._written[0] = 0
        self._stop_word[0] = 0
        self._events, child_events = self._ctx.Pipe(duplex=False)
        self._events_closed = False
        child_commands, self._commands = self._ctx.Pipe(duplex=False)
        goal_name = None
        if self.hook is not None:
            a = len(self.hook.ids)
            self._goal_shm = shared_memory.SharedMemory(create=True, size=_goal_size(a))
            (self._goal_seq_arr, self._goal_src, self._goals, self._delay_src, self._delay_bus,
             self._delay_n) = _goal_arrays(self._goal_shm.buf, a)
            self._goal_seq_arr[0] = self._delay_n[0] = 0
            goal_name = self._goal_shm.name
        self._proc = self._ctx.Process(
            target=_child, name="puppet-bus-reader", daemon=True,
            args=(self._shm.name, self.slots, self.port, self.servos, self.options, self.rate_hz,
                  child_events, child_commands, self.hook, goal_name))
        with children_deaf_to_ctrl_c():  # a terminal's Ctrl-C is the parent's: it stops the child
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
                raise ReaderProcessError(f"port {self.port}: the reader process did not start")
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
            self.log.append(payload)
        elif kind == "note":
            self.notes.append(payload)
        elif kind == "torque_off":
            self.torque_after = payload
        elif kind == "error":
            self._said_error = True
            self.stop()
            raise ReaderProcessError(
                payload if payload.startswith(f"port {self.port}:") else f"port {self.port}: {payload}")

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
                               self._ok[slot].copy(), late=self._late[slot].copy()))
        if int(self._written[0]) - first > self.slots - 1:  # overwritten while copying
            lost = int(self._written[0]) - self.slots + 1 - first
            out = out[lost:]
            self.dropped += lost
        self._read = written
        if not out and not self.alive:
            raise ReaderProcessError(f"port {self.port}: the reader process stopped")
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

    def request_reading(self) -> None:
        """Ask for a reading now: the child, if waiting for its next scheduled read, reads at
        once and goes on at rate_hz from there (a consumer that knows when it will want the
        next reading asks one bus transaction ahead, and gets a younger one). A child that is
        gone is not an error here: the next ``drain()`` reports it."""
        try:
            self._commands.send(("read", None))
        except (OSError, ValueError):
            pass

    def set_goals(self, goals: np.ndarray, src_t_ns: int) -> None:
        """The hook's goals, (a,) (NaN: hold; for actuators continuous ticks), solved from the
        reading taken at ``src_t_ns``; the child's hook gets them from its next cycle on."""
        seq = self._goal_seq_arr
        seq[0] += 1  # odd: being written
        self._goals[:] = goals
        self._goal_src[0] = src_t_ns
        seq[0] += 1

    def goal_delays_ms(self) -> np.ndarray:
        """(n,) ms from each sensor reading to the end of the hook's cycle call that wrote the
        goals solved from it (the newest DELAY_SLOTS; empty without a hook)."""
        if self._goal_shm is None:
            return np.zeros(0)
        n = min(int(self._delay_n[0]), DELAY_SLOTS)
        return (self._delay_bus[:n] - self._delay_src[:n]) / 1e6

    def stop(self, timeout: float = 3.0) -> None:
        """Stop the child and free the shared memory. A child that had ended before it was
        asked to, without an error message (killed, crashed), is named in ``died``; so is one
        that a signal killed while it was being asked (a SIGKILL not yet carried out when the
        stop began: a busy host runs the dying child late), other than this stop's own."""
        if self._proc is not None:
            if not self._proc.is_alive() and self._proc.exitcode and not self._said_error:
                self.died = self._death(self._proc.exitcode)
            self._stop_word[0] = 1
            try:
                self._commands.send(("stop", None))   # wakes a child pacing its reads
            except (OSError, ValueError):
                pass  # the child is gone already: its end of the pipe is closed
            # with a hook the child stops it first (torque off: a few transactions)
            self._proc.join(timeout if self.hook is None else max(timeout, 20.0))
            killed_here = self._proc.is_alive()
            if killed_here:
                self._proc.kill()
                self._proc.join()
            code = self._proc.exitcode
            if (self.died is None and not self._said_error and not killed_here and code is not None
                    and code < 0 and -code not in (signal.SIGINT, signal.SIGTERM)):  # the group's stops
                self.died = self._death(code)
            self._proc = None
            if self.hook is not None and self.report is not None:
                while not self._events_closed and self._events.poll():
                    try:
                        self._take_message()  # its torque-off report, if it got that far
                    except ReaderProcessError as err:  # its last words were an error
                        self.notes.append(str(err))
                if self.torque_after is None:  # the child died before its hook's stop
                    self.torque_after = self.hook.stop_from_parent(self.port, self.options,
                                                                   self.notes.append)
        if self._shm is not None:
            del self._t_ns, self._ticks, self._ok, self._late, self._written, self._stop_word
            self._shm.close()
            self._shm.unlink()
            self._shm = None
        if self._goal_shm is not None:
            del (self._goal_seq_arr, self._goal_src, self._goals, self._delay_src,
                 self._delay_bus, self._delay_n)
            self._goal_shm.close()
            self._goal_shm.unlink()
            self._goal_shm = None

    def _death(self, code: int) -> str:
        how = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"
        return f"port {self.port}: the reader process stopped ({how})"

    def __enter__(self) -> ReaderProcess:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
