"""The bus side of driving: setup before torque, group goal writes, the cycle's state read,
and the stop (torque off on every way out).

Setup writes only what it must (EEPROM items only with torque off, only when they differ) and
records every change; nothing here runs inside the loop except ``write_goals``,
``read_state`` and ``read_watchdogs``.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from puppet.bus.configure import (Change, SetupReport, ensure_status_return, identify,
                                  supports_fast_sync_read)
from puppet.bus.control_table import RETURN_DELAY_TIME, describe_hardware_error
from puppet.bus.errors import BusError, PortError, ServoCorrupt, ServoStatusError, ServoTimeout
from puppet.bus.link import SILENT, BusLink
from puppet.drive import items as it
from puppet.drive.errors import DriveError
from puppet.servo_models import MODELS

_STATE = struct.Struct("<BBhhiiiiHB")  # Moving .. Present Temperature (25 bytes)
ATTEMPTS = 3
"""Tries of a single-servo read or write outside the loop (a reply lost to noise is retried)."""
SILENCE_PATIENCE_S = 2.0
"""How long ``unanswered`` goes on asking a servo whose timeouts the line cannot prove silent."""
STALL_PATIENCE_S = 1.0
"""How long an instruction outside the loop that was not sent because the line was stalled
(replies still pending: a busy host) is tried again before it fails."""
IDENTIFY_ROUNDS = 3
IDENTIFY_PAUSE_S = 0.5
"""Rounds of pings (3 each) for servos that did not answer, this far apart, before refusing."""


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
        self.log = log
        self.changes: list[Change] = []
        self.recovered: list[int] = []
        self.setup: dict[int, ServoSetup] = {}
        self.fast_read = False  # Fast Sync Read for the state (every servo's firmware has it)
        self.velocity_unit_deg_s = np.array([MODELS[self.models[i]].velocity_unit_deg_s
                                             for i in self.ids])
        """(k,) degrees/s of the servo shaft per Profile / Present Velocity unit."""
        k = len(self.ids)
        self.state = State(*(np.zeros(k, bool) for _ in range(2)),
                           *(np.zeros(k, np.int64) for _ in range(6)))

    def read(self, dxl_id: int, item) -> int:
        """Read one item, tried up to ``ATTEMPTS`` times on a corrupt reply or a timeout the
        line proves silent, and for up to ``STALL_PATIENCE_S`` while replies are late."""
        return self._patient(lambda: self.link.read(dxl_id, item), dxl_id)

    def write(self, dxl_id: int, item, value: int) -> None:
        """Write one item (idempotent), tried like ``read``."""
        self._patient(lambda: self.link.write(dxl_id, item, value), dxl_id)

    def _patient(self, call, dxl_id: int | None = None, attempts: int = ATTEMPTS):
        """call() until it succeeds: tried ``attempts`` times on a corrupt reply or a timeout
        the line proves silent (``BusLink.witness``, asking the servo heard last), and for up
        to ``STALL_PATIENCE_S`` while it was not sent (the line stalled) or its reply may only
        be late (a busy host holds replies)."""
        deadline = time.monotonic() + STALL_PATIENCE_S
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

    def _change(self, dxl_id: int, item, old: int, new: int, why: str = "") -> None:
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
            missing, report.missing = report.missing, []
            identify(self.link, {i: self.models[i] for i in missing}, report)
        if report.missing:
            raise DriveError(f"servos {report.missing} did not answer on {self.link.port_name}")
        for dxl_id in self.ids:
            self.setup[dxl_id] = self._prepare_one(dxl_id, report.found[dxl_id].firmware,
                                                   use_watchdog)
        self.fast_read = supports_fast_sync_read(self.models, report.found)

    def _prepare_one(self, dxl_id: int, firmware: int, use_watchdog: bool) -> ServoSetup:
        link, model = self.link, self.models[dxl_id]
        info = ServoSetup(dxl_id, model, firmware)
        for attempt in range(ATTEMPTS):
            try:  # patient while the line is stalled (its writes set absolute values)
                self._patient(lambda: ensure_status_return(link, dxl_id, self.changes), dxl_id)
                break
            except (ServoTimeout, ServoCorrupt, ServoStatusError):  # a late reply misread
                if attempt == ATTEMPTS - 1:
                    raise
        hw = self.read(dxl_id, it.HARDWARE_ERROR_STATUS)
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
            wd = self.read(dxl_id, it.BUS_WATCHDOG)
            if wd == it.WATCHDOG_TRIPPED:
                self.recovered.append(dxl_id)
                self._change(dxl_id, it.BUS_WATCHDOG, wd, 0,
                             "its Bus Watchdog had stopped it: the host fell silent; cleared")
            elif wd != 0:
                self._change(dxl_id, it.BUS_WATCHDOG, wd, 0, "left set; cleared")
        torque = self.read(dxl_id, it.TORQUE_ENABLE)
        if torque:  # hold where it is before anything else
            self.write(dxl_id, it.GOAL_POSITION, self.read(dxl_id, it.PRESENT_POSITION))
        mode = self.read(dxl_id, it.OPERATING_MODE)
        drive = self.read(dxl_id, it.DRIVE_MODE)
        delay = self.read(dxl_id, RETURN_DELAY_TIME)
        unwanted = it.DRIVE_MODE_TORQUE_ON_BY_GOAL | it.DRIVE_MODE_TIME_PROFILE
        eeprom = mode not in it.POSITION_MODES or drive & unwanted or delay != 0
        if eeprom and torque:
            if mode not in it.POSITION_MODES:
                self.log(f"servo {dxl_id}: torque is on in operating mode {mode} (not a position "
                         "mode); turning torque off before changing it")
            self._change(dxl_id, it.TORQUE_ENABLE, 1, 0, "EEPROM items change only with torque off")
            torque = 0
        if mode not in it.POSITION_MODES:
            self._change(dxl_id, it.OPERATING_MODE, mode, it.POSITION_MODE, "perform drives positions")
            mode = it.POSITION_MODE
        if drive & unwanted:
            self._change(dxl_id, it.DRIVE_MODE, drive, drive & ~unwanted,
                         "no torque on by goal update; velocity-based profile")
        if delay != 0:
            self._change(dxl_id, RETURN_DELAY_TIME, delay, 0)
        if torque:
            self._change(dxl_id, it.TORQUE_ENABLE, 1, 0, "torque goes on only after the goal is set")
        info.mode = mode
        if mode == it.POSITION_MODE:
            info.lo = self.read(dxl_id, it.MIN_POSITION_LIMIT)
            info.hi = self.read(dxl_id, it.MAX_POSITION_LIMIT)
        info.temperature_limit = self.read(dxl_id, it.TEMPERATURE_LIMIT)
        info.current_unit_ma = unit = MODELS[model].current_unit_ma
        if unit is not None:
            info.current_limit_ma = self.read(dxl_id, it.CURRENT_LIMIT) * unit
        return info

    # ---- group writes ---------------------------------------------------------------------
    def write_all(self, item, values) -> None:
        """One Sync Write of ``item``: values (k,) in bus order, or one value for all (sent
        again while the line is stalled, up to ``STALL_PATIENCE_S``: a Sync Write has no reply,
        and one not sent changed nothing)."""
        if np.ndim(values) == 0:
            table = dict.fromkeys(self.ids, int(values))
        else:
            table = {i: int(v) for i, v in zip(self.ids, values)}
        self._patient(lambda: self.link.sync_write(item, table), attempts=1)

    def write_goals(self, goals: np.ndarray) -> None:
        """One Sync Write of Goal Position: (k,) float ticks, rounded."""
        self.link.sync_write(it.GOAL_POSITION,
                             {i: int(round(g)) for i, g in zip(self.ids, goals)})

    def rearm(self, dxl_id: int, units: int) -> int:
        """A servo its Bus Watchdog stopped (it reads -1, refuses goals; torque stays on):
        clear the watchdog, Goal Position := Present Position, watchdog ``units`` again ->
        that present position, raw ticks."""
        self.write(dxl_id, it.BUS_WATCHDOG, 0)
        raw = self.read(dxl_id, it.PRESENT_POSITION)
        self.write(dxl_id, it.GOAL_POSITION, raw)
        self.write(dxl_id, it.BUS_WATCHDOG, units)
        return raw

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
                    self.link.read(dxl_id, it.PRESENT_POSITION)
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
            value = self.read(i, it.TORQUE_ENABLE)
            if value != want:
                wrong[i] = value
        if wrong:
            raise DriveError(f"servos {sorted(wrong)}: Torque Enable reads {wrong}, expected {want}")

    # ---- the cycle's read -------------------------------------------------------------------
    def read_state(self) -> State:
        """One Sync Read (Fast Sync Read where every servo has it) of Moving .. Present
        Temperature (25 bytes) from every servo, with each status error byte kept (the alert
        bit). Fills and returns ``self.state``."""
        read = self.link.fast_sync_read if self.fast_read else self.link.sync_read
        result = read(self.ids, it.STATE)
        s = self.state
        s.failures = result.failed
        for n, dxl_id in enumerate(self.ids):
            s.alert[n] = bool(result.errors.get(dxl_id, 0) & 0x80)
            value = result.values.get(dxl_id)
            s.ok[n] = value is not None
            if value is None:
                continue
            (s.moving[n], s.moving_status[n], _pwm, s.current[n], s.velocity[n], s.position[n],
             _vt, _pt, _volt, s.temperature[n]) = _STATE.unpack(value.to_bytes(25, "little"))
        return s

    def read_watchdogs(self) -> dict[int, int]:
        """Bus Watchdog of every servo that has one (one Sync Read) -> {id: value}."""
        ids = [i for i in self.ids if self.setup.get(i, ServoSetup(i, "", 0)).watchdog]
        return self.link.sync_read(ids, it.BUS_WATCHDOG).values if ids else {}

    # ---- the stop ---------------------------------------------------------------------------
    def torque_off(self) -> dict[int, int | None]:
        """Torque off on every servo: one Sync Write that waits for no reply, then servo by
        servo (failures logged, the rest carried on), then read back -> {id: Torque Enable, or
        None when it could not be read}. Where torque reads 0 the Bus Watchdog is cleared."""
        try:
            self.write_all(it.TORQUE_ENABLE, 0)
        except BusError as err:
            self.log(f"torque off (group write) failed: {err}")
        for i in self.ids:
            try:
                self.write(i, it.TORQUE_ENABLE, 0)
            except PortError as err:
                self.log(f"servo {i}: torque off failed: {err}")
                break  # the port is gone: every further call would fail the same way
            except BusError as err:
                self.log(f"servo {i}: torque off failed: {err}")
        after: dict[int, int | None] = {}
        for i in self.ids:
            try:
                after[i] = _retried(lambda i=i: self.read(i, it.TORQUE_ENABLE))
            except BusError:
                after[i] = None
        for i, value in after.items():
            if value == 0 and self.setup.get(i, ServoSetup(i, "", 0)).watchdog:
                try:
                    _retried(lambda i=i: self._clear_watchdog(i))
                except BusError as err:
                    self.log(f"servo {i}: clearing the Bus Watchdog failed: {err}")
        return after

    def _clear_watchdog(self, dxl_id: int) -> None:
        if self.read(dxl_id, it.BUS_WATCHDOG) != 0:
            self.write(dxl_id, it.BUS_WATCHDOG, 0)


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
