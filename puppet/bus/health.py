"""Health of each servo (the bus events and their log live in ``puppet.events``)."""

from __future__ import annotations

from dataclasses import dataclass

from puppet.bus.errors import BusError

# Servo states.
OK = "ok"
FAILING = "failing"            # its last read failed; it is still in the group read
MISSING = "missing"            # it stopped answering; out of the group read, probed now and then
DUPLICATE = "duplicate_id"     # its replies collide, yet ping answers: another servo shares its id
CORRUPT = "corrupt"            # its replies keep arriving corrupt (CRC, truncated), ping too
PORT_DOWN = "port_down"        # the port itself is gone


@dataclass
class ServoHealth:
    """What the bus knows about one servo.

    state:             OK, FAILING, MISSING, DUPLICATE, CORRUPT or PORT_DOWN.
    consecutive_failures, failures: failed reads in a row, and in all.
    corrupt_in_a_row:  consecutive corrupt replies (a duplicate id shows as collisions).
    last_error:        the last BusError for this servo, or None.
    last_ok_ns:        monotonic time of its last good reading (0: never).
    hardware_error:    Hardware Error Status bits latched now (0: none).
    alert:             True when its last status packet carried the alert bit.
    out_of_limits:     its last raw value fell outside its tick limits (value not taken).
    dead_zone:         its last raw value was an end of its model's positions or beyond (an
                       AX, RX or XL-320 shaft in the 60° dead zone reads an end; not taken).
    reboots, rebases:  reboots detected; turn re-bases applied by the unwrapper.
    jitter:            running mean of |second difference| of its ticks (sensor noise), ticks.
    noisy:             jitter above the reader's noise threshold.
    """

    id: int
    model: str
    state: str = OK
    consecutive_failures: int = 0
    failures: int = 0
    corrupt_in_a_row: int = 0
    last_error: BusError | None = None
    last_ok_ns: int = 0
    hardware_error: int = 0
    alert: bool = False
    out_of_limits: bool = False
    dead_zone: bool = False
    reboots: int = 0
    rebases: int = 0
    jitter: float = 0.0
    noisy: bool = False
