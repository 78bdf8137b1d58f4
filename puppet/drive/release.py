"""Release a bus: torque off on every servo found, their Bus Watchdog cleared, read back.

What ``puppet release`` does after a program left servos with torque on (an adapter pulled
during ``perform``, a crash): the servos are every servo that answers a ping
(``puppet.bus.scan``) and, with a rig, the rig's too (``models``): a servo of another rig on
the same bus must not keep its torque because the wrong rig file was given; those are released
and named (``Released.others``). The stop itself is ``DriveBus.torque_off``.
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
    """Torque off and Bus Watchdog 0 (where the model has one) on every servo that answers a
    ping at ``port`` (a Protocol 2.0 broadcast ping, else a Protocol 1.0 ping of each id; with
    ``models`` ({id: model} of a rig, one protocol) only that protocol is pinged) and on
    ``models``' servos, read back. DriveError naming the port when nothing answers; PortError
    (PortInUse) when the port cannot be had."""
    out = Released()
    if models is None:
        models = _found_models(port, baud)
    else:
        models = dict(models)
        found = _found_models(port, baud, (protocol_of(models),), required=False)
        out.others = sorted(i for i in found if i not in models)
        if out.others:
            log(f"servo{'s' if len(out.others) > 1 else ''} {out.others} answered but "
                f"{'are' if len(out.others) > 1 else 'is'} not in the rig: released too")
        models |= found  # the model a servo reports over the rig's word for it
    link = BusLink(port, baud=baud, protocol=protocol_of(models))
    try:
        link.open()
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


def _found_models(port: str, baud: int, protocols=(2.0, 1.0), required: bool = True
                  ) -> dict[int, str]:
    """{id: model name} of the servos answering on ``port``: each of ``protocols`` in turn
    until one finds servos (a bus carries one); a model puppet does not know is left out,
    with a DriveError when nothing it knows answers (``required``; else {}). A protocol that
    finds servos is pinged PASSES times and the answers joined: a reply late on a busy bus
    must not leave a servo's torque on."""
    from puppet.bus.scan import scan

    for protocol in protocols:
        known: dict[int, str] = {}
        for _ in range(PASSES):
            found = scan(port, (baud,), (protocol,))
            known |= {f.id: f.model for f in found if f.model is not None}
            if not known:
                break  # nothing of this protocol: try the other
        if known:
            return dict(sorted(known.items()))
    if not required:
        return {}
    raise DriveError(f"port {port}: no servo of a known model answered a ping at {baud} bps "
                     "(Protocol 2.0 nor 1.0): nothing to release (check the power, the cable "
                     "and the baud rate)")
