"""Release a bus: torque off on every servo found, their Bus Watchdog cleared, read back.

What ``puppet release`` does after a program left servos with torque on (an adapter pulled
during ``perform``, a crash): the servos are the rig's (``models``) or, without a rig, every
servo that answers a broadcast ping; the stop itself is ``DriveBus.torque_off``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from puppet.bus.control_table import MODELS_BY_NUMBER
from puppet.bus.errors import BusError
from puppet.bus.link import BusLink
from puppet.drive import items as it
from puppet.drive.errors import DriveError
from puppet.drive.servos import DriveBus


@dataclass
class Released:
    """What ``release`` read back. torque / watchdog: {id: value, None when unreadable};
    missing: servos of the rig that did not answer."""

    torque: dict = field(default_factory=dict)
    watchdog: dict = field(default_factory=dict)
    missing: list = field(default_factory=list)


def release(port: str, models: dict[int, str] | None = None, *, baud: int = 1_000_000,
            log: Callable[[str], None] = lambda _line: None) -> Released:
    """Torque off and Bus Watchdog 0 on ``models``' servos ({id: model}; None: every servo a
    broadcast ping finds) at ``port``, read back. DriveError naming the port when nothing
    answers; PortError (PortInUse) when the port cannot be had."""
    link = BusLink(port, baud=baud)
    try:
        link.open()
        if models is None:
            found = link.broadcast_ping()
            if not found:
                raise DriveError(f"port {port}: no servo answered a broadcast ping at {baud} bps: "
                                 "nothing to release (check the power, the cable and the baud rate)")
            models = {i: getattr(MODELS_BY_NUMBER.get(number), "name", "?")
                      for i, (number, _) in sorted(found.items())}
        out = Released()
        # a read of its own (late replies on a busy host retried) tells who is there
        out.missing = sorted(DriveBus(link, list(models), models, log).unanswered(list(models)))
        ids = [i for i in models if i not in out.missing]
        if not ids:
            raise DriveError(f"port {port}: servos {out.missing} did not answer: nothing to release")
        bus = DriveBus(link, ids, {i: models[i] for i in ids}, log)
        out.torque = bus.torque_off()
        for dxl_id in ids:
            try:
                out.watchdog[dxl_id] = bus.read(dxl_id, it.BUS_WATCHDOG)
            except BusError as err:
                log(f"servo {dxl_id}: Bus Watchdog unreadable: {err}")
                out.watchdog[dxl_id] = None
        return out
    finally:
        link.close()
