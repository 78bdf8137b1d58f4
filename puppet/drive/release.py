"""Release a bus: torque off on every servo found, their Bus Watchdog cleared, read back.

What ``puppet release`` does after a program left servos with torque on (an adapter pulled
during ``perform``, a crash): the servos are the rig's (``models``) or, without a rig, every
servo that answers a ping (``puppet.bus.scan``); the stop itself is ``DriveBus.torque_off``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from puppet.bus.errors import BusError
from puppet.bus.link import BusLink
from puppet.drive.errors import DriveError
from puppet.drive.servos import DriveBus
from puppet.servo_models import protocol_of


@dataclass
class Released:
    """What ``release`` read back. torque / watchdog: {id: value, None when unreadable};
    missing: servos of the rig that did not answer."""

    torque: dict = field(default_factory=dict)
    watchdog: dict = field(default_factory=dict)
    missing: list = field(default_factory=list)


def release(port: str, models: dict[int, str] | None = None, *, baud: int = 1_000_000,
            log: Callable[[str], None] = lambda _line: None) -> Released:
    """Torque off and Bus Watchdog 0 (where the model has one) on ``models``' servos ({id:
    model}, one protocol; None: every servo a Protocol 2.0 broadcast ping finds, else every
    servo a Protocol 1.0 ping of each id finds) at ``port``, read back. DriveError naming the
    port when nothing answers; PortError (PortInUse) when the port cannot be had."""
    if models is None:
        models = _found_models(port, baud)
    link = BusLink(port, baud=baud, protocol=protocol_of(models))
    try:
        link.open()
        out = Released()
        # a read of its own (late replies on a busy host retried) tells who is there
        out.missing = sorted(DriveBus(link, list(models), models, log).unanswered(list(models)))
        ids = [i for i in models if i not in out.missing]
        if not ids:
            raise DriveError(f"port {port}: servos {out.missing} did not answer: nothing to release")
        bus = DriveBus(link, ids, {i: models[i] for i in ids}, log)
        out.torque = bus.torque_off()
        for dxl_id in ids:
            if bus.items[dxl_id].bus_watchdog is None:
                continue
            try:
                out.watchdog[dxl_id] = bus.read(dxl_id, "bus_watchdog")
            except BusError as err:
                log(f"servo {dxl_id}: Bus Watchdog unreadable: {err}")
                out.watchdog[dxl_id] = None
        return out
    finally:
        link.close()


PASSES = 2
"""Ping passes over the bus when ``release`` finds the servos itself."""


def _found_models(port: str, baud: int) -> dict[int, str]:
    """{id: model name} of the servos answering on ``port``: Protocol 2.0 first, then 1.0
    (a bus carries one); a model puppet does not know is left out, with a DriveError when
    nothing it knows answers. A protocol that finds servos is pinged PASSES times and the
    answers joined: a reply late on a busy bus must not leave a servo's torque on."""
    from puppet.bus.scan import scan

    for protocol in (2.0, 1.0):
        known: dict[int, str] = {}
        for _ in range(PASSES):
            found = scan(port, (baud,), (protocol,))
            known |= {f.id: f.model for f in found if f.model is not None}
            if not known:
                break  # nothing of this protocol: try the other
        if known:
            return dict(sorted(known.items()))
    raise DriveError(f"port {port}: no servo of a known model answered a ping at {baud} bps "
                     "(Protocol 2.0 nor 1.0): nothing to release (check the power, the cable "
                     "and the baud rate)")
