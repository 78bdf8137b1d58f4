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

EVENT_KINDS: dict[str, str] = {
    # the port
    "port_lost": "the port went away (USB unplugged, adapter reset); every servo reads not ok",
    "port_restored": "the port opened again; the servos in the group read were reconfigured",
    "read_error": "a read raised past the reader's own fault handling (the reader thread's net)",
    "transaction_failed": "a bookkeeping transaction (health, probe) failed; the readings stand",
    "fast_read_disabled": "servos answered Fast Sync Read with an error; Sync Read from now on",
    # one servo's replies
    "servo_failed": "a read of the servo failed (timeout, error status); it stays in the group",
    "servo_missing": "the servo stopped answering: out of the group read, probed now and then",
    "servo_recovered": "the servo read cleanly again after a failure",
    "duplicate_id": "corrupt replies in a row while ping answers: two servos share the id",
    "corrupt": "corrupt replies in a row (CRC, truncated), ping too: out of the group read",
    "out_of_limits": "the servo's value fell outside its tick limits and was not taken",
    "rebased": "the servo's raw position jumped (a reboot re-based it): turn offset updated",
    "noisy": "the servo's jitter rose above the noise threshold",
    "quiet": "the servo's jitter fell back below the noise threshold",
    # the servo's own state
    "hardware_error": "the servo latched a Hardware Error Status (overload, heat, voltage)",
    "hardware_error_cleared": "the servo's Hardware Error Status went back to 0",
    "reboot_sent": "a Reboot was sent to clear a latched hardware error",
    "reboot_failed": "a Reboot was sent and not acknowledged",
    "rebooted": "the servo's Realtime Tick fell behind: it rebooted (power cycle, brown-out)",
    "reconfigured": "the servo's settings were written again (after a reboot or a return)",
    "reconfigure_failed": "writing the servo's settings again failed",
    # driving actuators
    "write_failed": "a goal write to actuator servos failed",
    "watchdog_tripped": "an actuator's Bus Watchdog tripped (the host was silent): re-armed",
    "actuator_stopped": "an actuator was stopped, torque off (hardware error, reboot)",
    "port_gone": "the port stayed gone with actuators driven: their torque may still be on",
}
"""Every kind of bus event, with its meaning. ``BusEvent.kind`` is always one of these keys."""


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
