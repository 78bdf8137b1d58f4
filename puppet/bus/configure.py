"""Bus setup: find the mapped servos, check their models, configure them, report changes."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from puppet.bus.errors import BusError, ServoError, ServoModelMismatch, ServoStatusError, ServoTimeout
from puppet.bus.link import LATE, SILENT, BusLink
from puppet.servo_models import MODELS_BY_NUMBER, X_ITEMS, ControlItems, model_named, protocol_of


@dataclass(frozen=True)
class Change:
    """One control-table write made during setup: servo id, item name, old and new value."""

    id: int
    item: str
    old: int
    new: int


@dataclass
class ServoInfo:
    """What setup learned about one servo: model number and firmware version."""

    id: int
    model_number: int
    firmware: int


@dataclass
class SetupReport:
    """The outcome of ``ServoReader.open``.

    found:      {id: ServoInfo} for every mapped servo that answered.
    missing:    mapped ids that did not answer (they are flagged and probed later).
    unexpected: {id: model number} answering a broadcast ping but absent from the map
                (only filled when a broadcast ping was asked for).
    changes:    every write made (torque off, return delay 0, ...).
    hardware_errors: {id: Hardware Error Status bits} for servos with a latched error.
    read_mode:  'fast_sync_read' or 'sync_read' (Protocol 2.0); 'bulk_read', 'read' or
                'bulk_read + read' (Protocol 1.0: see ``p1_read_mode``).
    notes:      lines for the user about the port (its USB latency timer lowered, or how to).
    """

    found: dict[int, ServoInfo] = field(default_factory=dict)
    missing: list[int] = field(default_factory=list)
    unexpected: dict[int, int] = field(default_factory=dict)
    changes: list[Change] = field(default_factory=list)
    hardware_errors: dict[int, int] = field(default_factory=dict)
    read_mode: str = "sync_read"
    notes: list[str] = field(default_factory=list)


def identify(link: BusLink, servos: Mapping[int, str], report: SetupReport, attempts: int = 3) -> None:
    """Ping each mapped servo (up to ``attempts`` times), read its firmware, check its model.

    Fills ``report.found``/``report.missing``; raises ServoModelMismatch naming every servo
    whose model number differs from the map (the map is wrong or the wiring is).
    """
    mismatched: list[str] = []
    mismatched_ids: list[int] = []
    for dxl_id, model_name in servos.items():
        model = model_named(model_name)
        for attempt in range(attempts):
            try:
                number, firmware = link.ping(dxl_id)
                break
            except ServoError:
                continue
        else:
            report.missing.append(dxl_id)
            continue
        report.found[dxl_id] = ServoInfo(dxl_id, number, firmware)
        if number != model.number:
            found = MODELS_BY_NUMBER.get(number)
            mismatched_ids.append(dxl_id)
            mismatched.append(f"id {dxl_id}: map says {model.name} ({model.number}), servo reports "
                              f"{found.name if found else 'model'} ({number})")
    if mismatched:
        raise ServoModelMismatch(mismatched_ids, "ping", "; ".join(mismatched))


def bus_protocol(servos: Mapping[int, str], what: str = "the servo map") -> float:
    """The one protocol of ``servos`` ({id: model name}) -> 1.0 or 2.0 (``servo_models.
    protocol_of``); ValueError starting with ``what`` naming the servos of each otherwise."""
    try:
        return protocol_of(servos)
    except ValueError as err:
        raise ValueError(f"{what}: {err}") from None


def check_baud(servos: Mapping[int, str], baud: int, port: str = "") -> None:
    """BusError naming every servo of ``servos`` ({id: model name}) whose model cannot select
    ``baud`` bit/s (``ServoModel.baud_rates``: 4 Mbit/s on X-series, 1 Mbit/s at most on AX /
    RX and the XL-320, ...)."""
    slow: dict[str, list[int]] = {}
    for dxl_id, name in servos.items():
        if int(baud) not in model_named(name).baud_rates:
            slow.setdefault(name, []).append(int(dxl_id))
    if slow:
        names = "; ".join(f"servo{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))} ({m}: "
                          f"{_rates(model_named(m).baud_rates)})" for m, ids in slow.items())
        raise BusError(f"{'port ' + port + ': ' if port else ''}{baud} bit/s is not a rate of "
                       f"{names}")


def _rates(bauds) -> str:
    return "up to " + (f"{max(bauds) / 1e6:g} Mbit/s" if max(bauds) >= 1e6 else f"{max(bauds)} bit/s")


def p1_read_mode(servos: Mapping[int, str]) -> str:
    """How a Protocol 1.0 bus reads ``servos`` ({id: model name}), in words: 'bulk_read' (one
    Bulk Read, 0x92, of the MX servos: ``ServoModel.bulk_read``), 'read' (one Read per AX / RX
    servo: they have no Bulk Read, and Protocol 1.0 has no Sync Read) or 'bulk_read + read'."""
    bulk = [i for i, m in servos.items() if model_named(m).bulk_read]
    alone = [i for i in servos if i not in bulk]
    return " + ".join(name for name, ids in (("bulk_read", bulk), ("read", alone)) if ids)


def supports_fast_sync_read(servos: Mapping[int, str], found: Mapping[int, ServoInfo]) -> bool:
    """True when every found servo's firmware has Fast Sync Read (X330 FW >= 46, X430 >= 45;
    no Protocol 1.0 model, XL-320 or MX(2.0))."""
    return bool(found) and all(
        info.firmware >= model_named(servos[i]).fast_sync_read_firmware for i, info in found.items())


def ensure_status_return(link: BusLink, dxl_id: int, changes: list[Change],
                         items: ControlItems = X_ITEMS) -> None:
    """Status Return Level 2 (reply to everything), which the rest of the setup relies on.
    ``items``: the servo model's (``ServoModel.items``).

    At level 1 the servo answers reads but not writes; at level 0 only pings. The level is set
    by a write that expects no reply, then checked by a read. ServoError if it stays silent.
    """
    srl = items.status_return_level
    try:
        level = link.read(dxl_id, srl)
    except ServoTimeout as exc:
        # A pinged servo that ignores reads is at level 0, or its reply is only late (a loaded
        # machine): it answers pings, so a ping tells, by what arrives before its reply.
        verdict = link.witness(dxl_id, ping=True)
        if verdict != SILENT:
            exc.reply_late = verdict == LATE  # the late reply is read off the line: said so
            raise
        level = 0
    if level >= 2:
        return
    link.write_no_reply(dxl_id, srl, 2)
    changes.append(Change(dxl_id, srl.name, level, 2))
    if link.read(dxl_id, srl) != 2:
        raise ServoStatusError([dxl_id], "write Status Return Level", "the level did not change")


def configure_servo(link: BusLink, dxl_id: int, driven: bool, changes: list[Change],
                    items: ControlItems = X_ITEMS) -> None:
    """Status Return Level 2 and Return Delay Time 0 on one servo; a sensor's torque off.

    driven: the servo is an actuator that a driver owns (``ServoReader(driven=...)``): its
    torque is never changed here, and its return delay (an EEPROM item, writable only with
    torque off) only while its torque is off; the driver's own setup makes it safe to drive.
    ``items``: the servo model's (``ServoModel.items``: the addresses differ by protocol).
    Appends every write to ``changes``. Raises ServoError/PortError on a failed transaction.
    """
    ensure_status_return(link, dxl_id, changes, items)
    torque_item, delay_item = items.torque_enable, items.return_delay_time
    torque = link.read(dxl_id, torque_item)
    delay = link.read(dxl_id, delay_item)
    if delay != 0 and not (driven and torque):
        if torque:  # EEPROM is locked while torque is on
            link.write(dxl_id, torque_item, 0)
            changes.append(Change(dxl_id, torque_item.name, torque, 0))
            torque = 0
        link.write(dxl_id, delay_item, 0)
        changes.append(Change(dxl_id, delay_item.name, delay, 0))
    if not driven and torque:
        link.write(dxl_id, torque_item, 0)
        changes.append(Change(dxl_id, torque_item.name, torque, 0))


__all__ = ["Change", "ServoInfo", "SetupReport", "identify", "supports_fast_sync_read",
           "bus_protocol", "p1_read_mode", "check_baud",
           "configure_servo", "ensure_status_return"]
