"""The bus side of driving: setup before torque, group goal writes, the cycle's state read,
and the stop (torque off on every way out).

Setup writes only what it must (EEPROM items only with torque off, only when they differ) and
records every change; nothing here runs inside the loop except ``write_goals``,
``read_state`` and ``read_watchdogs``.

Every item is the servo's own (``items.resolve``: a ``ControlItems`` field name such as
"goal_position" is Goal Position 116 on an X-series servo, 30 on an AX), so one bus of one
protocol drives any mix of its models: group writes are one Sync Write per distinct item
(Protocol 1.0 has Sync Write too), the state read is ``BusLink.group_read`` (Fast Sync Read or
Sync Read on 2.0; Bulk Read on MX and one Read per AX / RX on 1.0). Protocol 1.0 has no
Operating Mode: joint (position) mode is CW / CCW Angle Limit not both 0, and a servo in wheel
mode is given its whole range (CCW Angle Limit := its top position); the XL-320's Control
Mode 2 is joint mode. A Protocol 1.0 servo reports a hardware condition in every status
instead of Hardware Error Status (``BusLink.hardware_error``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from puppet.bus.configure import (Change, SetupReport, check_baud, ensure_status_return,
                                  identify, supports_fast_sync_read)
from puppet.bus.errors import BusError, PortError, ServoCorrupt, ServoStatusError, ServoTimeout
from puppet.bus.link import SILENT, BusLink
from puppet.drive import items as it
from puppet.drive.errors import DriveError
from puppet.servo_models import MODELS, describe_hardware_error, protocol_of
ATTEMPTS = 3
"""Tries of a single-servo read or write outside the loop (a reply lost to noise is retried)."""
SILENCE_PATIENCE_S = 4.0
"""How long ``unanswered`` goes on asking servos whose timeouts the line cannot prove silent
(all of them together). A starved machine held a simulated bus's process off the CPU for
1-3.4 s (measured beside busy processes)."""
STALL_PATIENCE_S = 3.0
"""How long an instruction outside the loop that was not sent because the line was stalled
(replies still pending: a busy host), or whose timeout the line cannot prove a silence, is
tried again before it fails (see ``SILENCE_PATIENCE_S``)."""
UNHEARD_PATIENCE_S = 1.0
"""The same, for a servo asked again at setup when no servo has answered at all (a wrong
port, baud rate or protocol, or a bus still powering up): not worth ``STALL_PATIENCE_S`` per
servo."""
IDENTIFY_ROUNDS = 3
IDENTIFY_PAUSE_S = 0.5
"""Rounds for servos that did not answer (each asked patiently, ``_find_missing``), this far apart,
before refusing: a servo still booting."""


@dataclass
class ServoSetup:
    """What setup learned about one servo.

    mode: operating mode; lo/hi: its own goal limits in ticks (position mode) or None;
    temperature_limit: deg C; current_limit_ma: its Current Limit in mA, or None (no current
    item); current_unit_ma: the model's Present Current unit (None: it reports Present Load);
    watchdog: whether it has the Bus Watchdog.
    """

    id: int
    model: str
    firmware: int
    mode: int = it.POSITION_MODE
    lo: int | None = None
    hi: int | None = None
    temperature_limit: int = 70
    current_limit_ma: float | None = None
    current_unit_ma: float | None = None
    watchdog: bool = True


@dataclass
class State:
    """One cycle's read of every servo, (k,) arrays in bus order. ok: answered cleanly;
    alert: its status carried the alert bit (a hardware error is latched)."""

    ok: np.ndarray
    alert: np.ndarray
    moving: np.ndarray
    moving_status: np.ndarray
    current: np.ndarray
    velocity: np.ndarray
    position: np.ndarray
    temperature: np.ndarray
    failures: dict = field(default_factory=dict)


class DriveBus:
    """Drives the servos ``ids`` (bus order) of ``models`` ({id: model name}) on ``link``.

    log: called with one line of text for every change, recovery and failure.
    """

    def __init__(self, link: BusLink, ids, models: dict[int, str], log: Callable[[str], None]):
        self.link = link
        self.ids = [int(i) for i in ids]
        self.models = {int(i): m for i, m in models.items()}
        if protocol_of(self.models) != link.protocol:
            raise ValueError(f"DriveBus: servos {self.ids} speak Protocol "
                             f"{protocol_of(self.models):.1f}, the link {link.protocol:.1f}")
        check_baud(self.models, link.baud, link.port_name)
        self.log = log
        self.changes: list[Change] = []
        self.recovered: list[int] = []
        self.setup: dict[int, ServoSetup] = {}
        self.fast_read = False  # Fast Sync Read for the state (every servo's firmware has it)
        self.items = {i: MODELS[self.models[i]].items for i in self.ids}
        """{id: ControlItems} of each servo's model."""
        self.layouts = {i: it.StateLayout.of(self.items[i]) for i in self.ids}
        self._bulk = [i for i in self.ids if MODELS[self.models[i]].bulk_read]
        self.velocity_unit_deg_s = np.array([MODELS[self.models[i]].velocity_unit_deg_s
                                             for i in self.ids])
        """(k,) degrees/s of the servo shaft per Moving Speed / Profile Velocity unit."""
        self.speed_max = np.array([it.MOVING_SPEED_MAX[self.items[i].moving_speed.size]
                                   for i in self.ids])
        """(k,) the largest Moving Speed / Profile Velocity of each servo."""
        k = len(self.ids)
        self.state = State(*(np.zeros(k, bool) for _ in range(2)),
                           *(np.zeros(k, np.int64) for _ in range(6)))

    def item(self, dxl_id: int, what):
        """The item ``what`` (a ControlItems field name or an Item) on servo ``dxl_id``'s model;
        DriveError naming the servo when its model has none."""
        item = it.resolve(self.items[dxl_id], what)
        if item is None:
            raise DriveError(f"servo {dxl_id} ({self.models[dxl_id]}) has no "
                             f"{what if isinstance(what, str) else what.name}")
        return item

    def read(self, dxl_id: int, what) -> int:
        """Read one item (a ControlItems field name or an Item), tried up to ``ATTEMPTS`` times
        on a corrupt reply or a timeout the line proves silent, and for up to
        ``STALL_PATIENCE_S`` while replies are late."""
        item = self.item(dxl_id, what)
        return self._patient(lambda: self.link.read(dxl_id, item), dxl_id)

    def write(self, dxl_id: int, what, value: int) -> None:
        """Write one item (idempotent), tried like ``read``."""
        item = self.item(dxl_id, what)
        self._patient(lambda: self.link.write(dxl_id, item, value), dxl_id)

    def hardware_error(self, dxl_id: int) -> int:
        """Hardware Error Status bits of one servo (``BusLink.hardware_error``), tried like
        ``read``."""
        return self._patient(lambda: self.link.hardware_error(dxl_id, self.items[dxl_id]), dxl_id)

    def _patient(self, call, dxl_id: int | None = None, attempts: int = ATTEMPTS,
                 patience_s: float = STALL_PATIENCE_S):
        """call() until it succeeds: tried ``attempts`` times on a corrupt reply or a timeout
        the line proves silent (``BusLink.witness``, asking the servo heard last), and for up
        to ``patience_s`` while it was not sent (the line stalled) or its reply may only
        be late (a busy host holds replies)."""
        deadline = time.monotonic() + patience_s
        tries = 0
        while True:
            try:
                return call()
            except (ServoTimeout, ServoCorrupt) as exc:
                if time.monotonic() < deadline:
                    if exc.line_stalled:
                        continue
                    if exc.deadline and dxl_id is not None:
                        witness = self.link.heard_last(other_than=dxl_id)
                        if witness is None or self.link.witness(witness) != SILENT:
                            continue
                tries += 1
                if tries >= attempts:
                    raise

    def _find_missing(self, report: SetupReport) -> None:
        """Ask each servo of ``report.missing`` again, patiently (``_patient``: a ping's timeout
        counts once the line proves the silence; a starved host's late reply does not make a
        servo missing), and identify those that answer into ``report``."""
        missing, report.missing = report.missing, []
        answered = {}
        patience_s = STALL_PATIENCE_S if report.found else UNHEARD_PATIENCE_S
        for dxl_id in missing:
            try:
                self._patient(lambda: self.link.ping(dxl_id), dxl_id, patience_s=patience_s)
                answered[dxl_id] = self.models[dxl_id]
            except PortError:
                raise
            except BusError:
                report.missing.append(dxl_id)
        if answered:
            identify(self.link, answered, report)

    def _change(self, dxl_id: int, what, old: int, new: int, why: str = "") -> None:
        item = self.item(dxl_id, what)
        self.write(dxl_id, item, new)
        self.changes.append(Change(dxl_id, item.name, old, new))
        self.log(f"servo {dxl_id}: {item.name} {old} -> {new}{' (' + why + ')' if why else ''}")

    # ---- before torque ----------------------------------------------------------------------
    def prepare(self, use_watchdog: bool) -> None:
        """Find every servo and make it safe to drive, torque left off. Refuses (DriveError,
        naming the servo) a missing servo, a latched hardware error, a firmware without the
        Bus Watchdog (unless ``use_watchdog`` is False). Recovers a tripped watchdog."""
        report = SetupReport()
        identify(self.link, self.models, report)
        for _ in range(IDENTIFY_ROUNDS - 1):  # a servo still booting, a reply lost to noise
            if not report.missing:
                break
            time.sleep(IDENTIFY_PAUSE_S)
            self._find_missing(report)
        if report.missing:
            raise DriveError(f"servos {report.missing} did not answer on {self.link.port_name}")
        for dxl_id in self.ids:
            self.setup[dxl_id] = self._prepare_one(dxl_id, report.found[dxl_id].firmware,
                                                   use_watchdog)
        self.fast_read = supports_fast_sync_read(self.models, report.found)

    def _prepare_one(self, dxl_id: int, firmware: int, use_watchdog: bool) -> ServoSetup:
        link, model = self.link, self.models[dxl_id]
        items = self.items[dxl_id]
        info = ServoSetup(dxl_id, model, firmware)
        for attempt in range(ATTEMPTS):
            try:  # patient while the line is stalled (its writes set absolute values)
                self._patient(lambda: ensure_status_return(link, dxl_id, self.changes, items),
                              dxl_id)
                break
            except (ServoTimeout, ServoCorrupt, ServoStatusError):  # a late reply misread
                if attempt == ATTEMPTS - 1:
                    raise
        hw = self.hardware_error(dxl_id)
        while hw and (again := self.hardware_error(dxl_id)) != hw:
            hw = again  # a late reply to another 1-byte read, misread: a latched error stays
        if hw:
            raise DriveError(f"servo {dxl_id}: hardware error latched ({describe_hardware_error(hw)}); "
                             "let it cool or fix the load, then power-cycle or reboot it")
        first = MODELS[model].bus_watchdog_firmware
        info.watchdog = first is not None and firmware >= first
        if not info.watchdog and use_watchdog:
            needs = (f"firmware {firmware} has no Bus Watchdog (needs >= {first})" if first
                     else f"model {model} has no Bus Watchdog")
            raise DriveError(
                f"servo {dxl_id}: {needs}: if this host died the servo would keep its last "
                "goal with torque on; update the firmware, or pass --no-watchdog to perform anyway")
        if info.watchdog:
            wd = self.read(dxl_id, "bus_watchdog")
            if wd == it.WATCHDOG_TRIPPED:
                self.recovered.append(dxl_id)
                self._change(dxl_id, "bus_watchdog", wd, 0,
                             "its Bus Watchdog had stopped it: the host fell silent; cleared")
            elif wd != 0:
                self._change(dxl_id, "bus_watchdog", wd, 0, "left set; cleared")
        torque = self.read(dxl_id, "torque_enable")
        if torque:  # hold where it is before anything else
            self.write(dxl_id, "goal_position", self.read(dxl_id, "present_position"))
        x = it.x_layout(items)
        if x:
            mode = self.read(dxl_id, "operating_mode")
            joint = mode in it.POSITION_MODES
            drive = self.read(dxl_id, "drive_mode")
        elif items.operating_mode is not None:  # XL-320 Control Mode: 2 joint, 1 wheel
            mode = self.read(dxl_id, "operating_mode")
            joint, drive = mode == it.XL320_JOINT_MODE, 0
        else:  # Protocol 1.0: wheel mode is CW and CCW Angle Limit both 0
            cw, ccw = (self.read(dxl_id, "min_position_limit"),
                       self.read(dxl_id, "max_position_limit"))
            mode, joint, drive = None, bool(cw or ccw), 0
        delay = self.read(dxl_id, "return_delay_time")
        unwanted = it.DRIVE_MODE_TORQUE_ON_BY_GOAL | it.DRIVE_MODE_TIME_PROFILE
        eeprom = not joint or drive & unwanted or delay != 0
        if eeprom and torque:
            if not joint:
                self.log(f"servo {dxl_id}: torque is on in "
                         + (f"operating mode {mode}" if mode is not None else "wheel mode")
                         + " (not a position mode); turning torque off before changing it")
            self._change(dxl_id, "torque_enable", 1, 0, "EEPROM items change only with torque off")
            torque = 0
        if not joint and x:
            self._change(dxl_id, "operating_mode", mode, it.POSITION_MODE, "perform drives positions")
        elif not joint and mode is not None:
            self._change(dxl_id, "operating_mode", mode, it.XL320_JOINT_MODE,
                         "perform drives positions (joint mode)")
        elif not joint:
            top = MODELS[model].max_position
            self._change(dxl_id, "max_position_limit", 0, top,
                         "perform drives positions: joint mode, its whole range")
        if drive & unwanted:
            self._change(dxl_id, "drive_mode", drive, drive & ~unwanted,
                         "no torque on by goal update; velocity-based profile")
        if delay != 0:
            self._change(dxl_id, "return_delay_time", delay, 0)
        if torque:
            self._change(dxl_id, "torque_enable", 1, 0, "torque goes on only after the goal is set")
        info.mode = it.POSITION_MODE if not x or not joint else mode
        if info.mode == it.POSITION_MODE:
            info.lo = self.read(dxl_id, "min_position_limit")
            info.hi = self.read(dxl_id, "max_position_limit")
        info.temperature_limit = self.read(dxl_id, "temperature_limit")
        if not self.layouts[dxl_id].load:
            info.current_unit_ma = unit = MODELS[model].current_unit_ma
            info.current_limit_ma = self.read(dxl_id, "current_limit") * unit
        return info

    # ---- group writes ---------------------------------------------------------------------
    def write_all(self, what, values) -> None:
        """One Sync Write of ``what`` (a ControlItems field name or an Item) per distinct item
        among the servos whose model has it (the others are skipped): values (k,) in bus order,
        or one value for all (sent again while the line is stalled, up to ``STALL_PATIENCE_S``:
        a Sync Write has no reply, and one not sent changed nothing)."""
        values = np.broadcast_to(np.asarray(values), (len(self.ids),))
        tables = self._tables(what, values)
        for item, table in tables.items():
            self._patient(lambda item=item, table=table: self.link.sync_write(item, table),
                          attempts=1)

    def _tables(self, what, values) -> dict:
        """{Item: {id: int value}} of ``what`` for the servos whose model has it."""
        tables: dict = {}
        for dxl_id, value in zip(self.ids, values):
            item = it.resolve(self.items[dxl_id], what)
            if item is not None:
                tables.setdefault(item, {})[dxl_id] = int(round(float(value)))
        return tables

    def write_goals(self, goals: np.ndarray) -> None:
        """One Sync Write of Goal Position per goal item (one on a bus of one family): (k,)
        float ticks, rounded."""
        for item, table in self._tables("goal_position", goals).items():
            self.link.sync_write(item, table)

    def write_goal_table(self, table: dict[int, int]) -> None:
        """Sync Write Goal Position {id: raw ticks} (one write per goal item)."""
        items = self.items
        first = items[next(iter(table))].goal_position if table else None
        if all(items[i].goal_position == first for i in table):
            if table:
                self.link.sync_write(first, table)
            return
        by_item: dict = {}
        for dxl_id, value in table.items():
            by_item.setdefault(items[dxl_id].goal_position, {})[dxl_id] = value
        for item, part in by_item.items():
            self.link.sync_write(item, part)

    def rearm(self, dxl_id: int, units: int) -> int:
        """A servo its Bus Watchdog stopped (it reads -1, refuses goals; torque stays on):
        clear the watchdog, Goal Position := Present Position (within the servo's own goal
        limits: a shaft pushed past one would have the goal refused, "data range error"),
        watchdog ``units`` again -> that goal, raw ticks."""
        self.write(dxl_id, "bus_watchdog", 0)
        goal = self.read(dxl_id, "present_position")
        setup = self.setup.get(dxl_id)
        if setup is not None and setup.lo is not None and setup.hi is not None:
            goal = min(max(goal, setup.lo), setup.hi)
        self.write(dxl_id, "goal_position", goal)
        self.write(dxl_id, "bus_watchdog", units)
        return goal

    def unanswered(self, ids, patience_s: float = SILENCE_PATIENCE_S) -> dict[int, BusError]:
        """Of ``ids``, those that fail a read of their own -> {id: its error}. A group read
        fails as a whole when one servo is silent (one Fast Sync Read reply packet): this finds
        which. A timeout counts only once the line proves the silence (``BusLink.witness``,
        asking a servo that answered) or once ``patience_s`` (for the whole call) has passed
        (a busy host holds replies); a corrupt or error reply after ``ATTEMPTS``. PortError is
        raised."""
        heard = [i for i in self.ids if i not in ids]
        out = {}
        deadline = time.monotonic() + patience_s  # for them all: a bus gone quiet costs it once
        for dxl_id in ids:
            tries = 0
            while True:
                try:
                    self.link.read(dxl_id, self.items[dxl_id].present_position)
                    heard.append(dxl_id)
                    break
                except PortError:
                    raise
                except ServoTimeout as err:
                    late = err.line_stalled or not heard or self.link.witness(heard[-1]) != SILENT
                    if late and time.monotonic() < deadline:
                        continue
                    out[dxl_id] = err
                    break
                except ServoCorrupt as err:  # a late reply to another read, misread: ask again
                    if time.monotonic() < deadline:
                        continue
                    out[dxl_id] = err
                    break
                except BusError as err:
                    tries += 1
                    if tries >= ATTEMPTS:
                        out[dxl_id] = err
                        break
        return out

    def check_torque(self, want: int) -> None:
        """Read Torque Enable back from every servo; DriveError naming those that differ."""
        wrong = {}
        for i in self.ids:
            value = self.read(i, "torque_enable")
            if value != want:
                wrong[i] = value
        if wrong:
            raise DriveError(f"servos {sorted(wrong)}: Torque Enable reads {wrong}, expected {want}")

    # ---- the cycle's read -------------------------------------------------------------------
    def read_state(self) -> State:
        """Each servo's state block (``items.StateLayout``: Moving .. Present Temperature, 25
        bytes, on the X layout) by ``BusLink.group_read`` (Fast Sync Read where every servo
        has it, else Sync Read; on Protocol 1.0 Bulk Read on MX, a Read per AX / RX), with each
        status error byte kept (the alert bit). Fills and returns ``self.state``."""
        result = self.link.group_read({i: self.layouts[i].block for i in self.ids},
                                      fast=self.fast_read, bulk=self._bulk)
        s = self.state
        s.failures = result.failed
        for n, dxl_id in enumerate(self.ids):
            s.alert[n] = bool(result.errors.get(dxl_id, 0) & 0x80)
            value = result.values.get(dxl_id)
            s.ok[n] = value is not None
            if value is None:
                continue
            f = self.layouts[dxl_id].decode(value)
            s.moving[n], s.moving_status[n], s.current[n] = f["moving"], f["moving_status"], f["current"]
            s.velocity[n], s.position[n], s.temperature[n] = f["velocity"], f["position"], f["temperature"]
        return s

    def read_watchdogs(self) -> dict[int, int]:
        """Bus Watchdog of every servo that has one (one Sync Read) -> {id: value}."""
        ids = [i for i in self.ids if self._has_watchdog(i)]
        return self.link.group_read({i: self.items[i].bus_watchdog for i in ids}).values if ids else {}

    def _has_watchdog(self, dxl_id: int) -> bool:
        """The servo has a Bus Watchdog (its model has the item; its firmware, once setup
        has read it)."""
        setup = self.setup.get(dxl_id)
        return self.items[dxl_id].bus_watchdog is not None and (setup is None or setup.watchdog)

    # ---- the stop ---------------------------------------------------------------------------
    def torque_off(self) -> dict[int, int | None]:
        """Torque off on every servo: one Sync Write that waits for no reply, then servo by
        servo (failures logged, the rest carried on), then read back -> {id: Torque Enable, or
        None when it could not be read}. Where torque reads 0 the Bus Watchdog is cleared."""
        try:
            self.write_all("torque_enable", 0)
        except BusError as err:
            self.log(f"torque off (group write) failed: {err}")
        for i in self.ids:
            try:
                self.write(i, "torque_enable", 0)
            except PortError as err:
                self.log(f"servo {i}: torque off failed: {err}")
                break  # the port is gone: every further call would fail the same way
            except BusError as err:
                self.log(f"servo {i}: torque off failed: {err}")
        after: dict[int, int | None] = {}
        for i in self.ids:
            try:
                after[i] = _retried(lambda i=i: self.read(i, "torque_enable"))
            except BusError:
                after[i] = None
        for i, value in after.items():
            if value == 0 and self._has_watchdog(i):
                try:
                    _retried(lambda i=i: self._clear_watchdog(i))
                except BusError as err:
                    self.log(f"servo {i}: clearing the Bus Watchdog failed: {err}")
        return after

    def _clear_watchdog(self, dxl_id: int) -> None:
        """Bus Watchdog := 0, always written and read back (a read first that found it 0 could
        skip the write: CI once left a stopped actuator's watchdog armed, torque read back off)."""
        self.write(dxl_id, "bus_watchdog", 0)
        if self.read(dxl_id, "bus_watchdog") != 0:
            raise ServoCorrupt([dxl_id], "clear bus_watchdog", "it still reads armed after the write")


STOP_ATTEMPTS = 3
"""Tries of each read-back and watchdog clear on the way out: a reply lost once (a busy host or
a noisy line) must not leave a servo reported unknown or its watchdog armed."""


def _retried(call, attempts: int = STOP_ATTEMPTS):
    """call() until it returns without a timeout or corrupt reply (a PortError ends it at once)."""
    for attempt in range(attempts):
        try:
            return call()
        except PortError:
            raise
        except BusError:
            if attempt == attempts - 1:
                raise
