"""Bus events: the declared kinds, one event (``BusEvent``) and the bounded log of them
(``EventLog``).

The bus makes events; the loop, the view, the summary and the command line read them. This
module imports no servo stack (``dynamixel_sdk``, ``serial``, ``termios``), so every reader of
events imports it on any OS. ``EVENT_KINDS`` is the contract: ``EventLog.add`` refuses a kind that
is not in it.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

class EventKind(NamedTuple):
    """One kind of bus event. meaning: what happened, for developers; fault: something a
    puppeteer should act on (else a return to normal, or bookkeeping); words: what it means to a
    puppeteer, short (the view's fault log and "last fault", the summary)."""

    meaning: str
    fault: bool
    words: str


EVENT_KINDS: dict[str, EventKind] = {
    # the port
    "port_lost": EventKind("the port went away (USB unplugged, adapter reset); every servo reads not ok",
        True, "adapter unplugged or reset: no servo answers"),
    "port_restored": EventKind("the port opened again; the servos in the group read were reconfigured",
        False, "adapter back: servos answering again"),
    "read_error": EventKind("a read raised past the reader's own fault handling (the reader thread's net)",
        True, "reading the servos failed unexpectedly"),
    "transaction_failed": EventKind("a bookkeeping transaction (health, probe) failed; the readings stand",
        False, "a background check of the servos failed (readings fine)"),
    "fast_read_disabled": EventKind("servos answered Fast Sync Read with an error; Sync Read from now on",
        False, "servos refused fast reads: slower reads from now on"),
    # one servo's replies
    "servo_failed": EventKind("a read of the servo failed (timeout, error status); it stays in the group",
        True, "servo missed a reading"),
    "servo_missing": EventKind("the servo stopped answering: out of the group read, probed now and then",
        True, "servo stopped answering (cable? power?)"),
    "late_reply": EventKind("a servo's reply missed its deadline but the line shows it on its way, or "
        "cannot tell (a starved host holds replies): its last good value held for that reading, no "
        "failure booked (a servo unheard for the reader's stall_limit_s is booked failed)",
        False, "reply came late (busy computer): last angle held a moment"),
    "servo_recovered": EventKind("the servo read cleanly again after a failure",
        False, "servo answering again"),
    "duplicate_id": EventKind("corrupt replies in a row while ping answers: two servos share the id",
        True, "two servos share this id"),
    "corrupt": EventKind("corrupt replies in a row (CRC, truncated), ping too: out of the group read",
        True, "garbled replies (loose cable or noise)"),
    "out_of_limits": EventKind("the servo's value fell outside its tick limits and was not taken",
        True, "servo reported a position outside its limits"),
    "dead_zone": EventKind("the servo read an end of its model's positions (an AX, RX or XL-320 "
        "shaft in its 60° dead zone reads 0 or 1023, whatever its angle): not taken",
        True, "servo turned into its blind zone: no angle there"),
    "rebased": EventKind("the servo's raw position jumped (a reboot re-based it): turn offset updated",
        False, "servo restarted: its position was re-based"),
    "noisy": EventKind("the servo's jitter rose above the noise threshold",
        True, "servo reading is jittery"),
    "quiet": EventKind("the servo's jitter fell back below the noise threshold",
        False, "servo reading steady again"),
    # the servo's own state
    "hardware_error": EventKind("the servo latched a Hardware Error Status (overload, heat, voltage)",
        True, "servo shut itself off (overload, heat or voltage)"),
    "hardware_error_cleared": EventKind("the servo's Hardware Error Status went back to 0",
        False, "servo's error cleared"),
    "reboot_sent": EventKind("a Reboot was sent to clear a latched hardware error",
        False, "restarting the servo to clear its error"),
    "reboot_failed": EventKind("a Reboot was sent and not acknowledged",
        True, "servo did not restart"),
    "rebooted": EventKind("the servo's Realtime Tick fell behind: it rebooted (power cycle, brown-out)",
        True, "servo lost power and restarted"),
    "reconfigured": EventKind("the servo's settings were written again (after a reboot or a return)",
        False, "servo settings restored"),
    "reconfigure_failed": EventKind("writing the servo's settings again failed",
        True, "could not restore the servo's settings"),
    # driving actuators
    "write_failed": EventKind("a goal write to actuator servos failed",
        True, "could not send a move to the motors"),
    "watchdog_tripped": EventKind("an actuator's Bus Watchdog tripped (the host was silent): re-armed",
        True, "motor stopped: the computer went quiet too long (restarted)"),
    "actuator_stopped": EventKind("an actuator was stopped, torque off (hardware error, reboot)",
        True, "motor stopped, torque off"),
    "port_gone": EventKind("the port stayed gone with actuators driven: their torque may still be on",
        True, "adapter gone while motors were driven: their torque may still be on"),
}
"""Every kind of bus event, with its meaning. ``BusEvent.kind`` is always one of these keys."""

HELD_READING = "held_reading"
LOOP_KINDS: dict[str, EventKind] = {
    HELD_READING: EventKind("a reading with a servo's value held (not read this time): its reply came "
        "late (late_reply) or the servo is at fault (its own event says which)",
        False, "servo's last angle held (reply late or missing)"),
}
"""What the loop counts in its summary beside the bus events (never logged by the bus)."""

CONDITIONS: dict[str, EventKind] = {**EVENT_KINDS, **LOOP_KINDS}
"""The one table of names: the summary, the terminal, the page and the overlay's legend name a
condition by its key here and describe it in its ``words``."""


def describe_counts(counts: dict[str, int]) -> str:
    """A count per kind ({kind: n}) as one line: faults first, then the other events (a kind
    not in CONDITIONS counts as a fault)."""
    faults = [f"{k} {n}" for k, n in sorted(counts.items()) if k not in CONDITIONS or CONDITIONS[k].fault]
    other = [f"{k} {n}" for k, n in sorted(counts.items()) if k in CONDITIONS and not CONDITIONS[k].fault]
    line = ", ".join(faults) or "none"
    return f"{line}; other events: {', '.join(other)}" if other else line


@dataclass(frozen=True)
class BusEvent:
    """Something that happened on the bus.

    t_ns:   monotonic time, ns.
    kind:   a key of EVENT_KINDS.
    ids:    the servos concerned (empty for port events).
    detail: human-readable context.
    """

    t_ns: int
    kind: str
    ids: tuple[int, ...]
    detail: str = ""


@dataclass
class EventLog:
    """A bounded log of BusEvents (the newest ``maxlen``, oldest dropped first) and a running
    count per kind (at most one entry per EVENT_KINDS key)."""

    maxlen: int = 1000
    events: deque = field(init=False)
    counts: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.events = deque(maxlen=self.maxlen)

    def add(self, kind: str, ids=(), detail: str = "") -> BusEvent:
        """Log a new event of ``kind`` (a key of EVENT_KINDS, else ValueError naming it) now."""
        if kind not in EVENT_KINDS:
            raise ValueError(f"EventLog.add: unknown bus event kind {kind!r} (puppet/events.py "
                             "EVENT_KINDS lists every kind)")
        return self.append(BusEvent(time.monotonic_ns(), kind, tuple(int(i) for i in ids), detail))

    def append(self, event: BusEvent) -> BusEvent:
        """Log an event made elsewhere (another process's log), keeping its time."""
        self.events.append(event)
        self.counts[event.kind] = self.counts.get(event.kind, 0) + 1
        return event

    def drain(self) -> list[BusEvent]:
        """All events since the last drain, oldest first."""
        out = []
        while True:
            try:
                out.append(self.events.popleft())
            except IndexError:
                return out
