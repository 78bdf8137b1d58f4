"""ServoReader: one group read of Present Position per call, with fault isolation and recovery.

Per ``read()``:
1. If the port is down, try to rebuild it (at most every ``reconnect_period_s``).
2. One group read of the servos in the group, the fastest transaction each model has: on
   Protocol 2.0 Fast Sync Read where every servo's firmware has it, Sync Read otherwise (one
   per Present Position item: an XL-320 keeps it at 37, 2 bytes, the others at 132, 4 bytes);
   on Protocol 1.0, which has no Sync Read, one Bulk Read (0x92) of the MX servos and one Read
   per AX / RX servo (they have no Bulk Read). Servos that answered keep their values even if
   others failed. On a model with a dead zone (AX, RX, XL-320: 1024 positions over 300°) a
   value at either end (0 or max_position: what the servo reads anywhere in its 60° dead zone)
   or beyond is flagged (``dead_zone`` event, ``ServoHealth.dead_zone``), never taken: the
   joint holds its last good angle (rig load keeps joint limits inside the positions).
3. Each servo the group read failed for gets one individual read; a servo that still fails
   holds its last good value, is flagged (``ok`` False), and after ``missing_after`` failures
   in a row leaves the group read: it is then probed alone every ``probe_period_s``, so a dead
   servo costs the others one timeout per probe, not one per frame. A timeout is booked as a
   failure only once the line proves the servo silent (``BusLink.witness``: a servo that
   answered is asked for a read; its reply arriving with nothing before it proves the silence). On a
   starved machine the kernel can hold replies for hundreds of ms: a late or unproven
   timeout leaves the reading flagged for that servo (its last good value held) and is logged
   as a ``late_reply`` (not a fault), booking nothing, unless the servo has been unheard for ``stall_limit_s`` (a whole bus gone quiet
   has no witness).
4. Every ``health_period_s`` (and at once when a status packet carries the alert bit): Hardware
   Error Status and Realtime Tick of every servo. A latched hardware error is reported (and the
   servo rebooted when ``auto_reboot`` allows); a Realtime Tick behind its expected value means
   the servo rebooted: it is reconfigured. Protocol 1.0 has neither item nor Reboot: the
   hardware bits of each servo's latest status are reported (input voltage, overheating,
   overload), nothing is rebooted, and a servo that rebooted needs nothing back (its settings
   are EEPROM, its position absolute); one that stopped answering meanwhile is reconfigured
   when it returns, as on Protocol 2.0. The same for the XL-320's missing Realtime Tick.
A servo that comes back (from missing, a reboot, a rebuilt port) is reconfigured; its turn count
is unwrapped to stay continuous (see ``unwrap``). Nothing the SDK raises escapes ``read()``.
A driven servo (an actuator whose driver plugs into the ReaderProcess hook) is read and
recovered like the others, but nothing here changes its torque or reboots it: its driver decides.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping

import dynamixel_sdk
import numpy as np

from puppet.bus import health as hs
from puppet.bus.codec import ALERT_BIT
from puppet.bus.configure import (SetupReport, bus_protocol, check_baud, configure_servo,
                                  identify, p1_read_mode, supports_fast_sync_read)
from puppet.bus.errors import PortError, ServoCorrupt, ServoError, ServoMissing, ServoTimeout
from puppet.bus.link import LATE, SILENT, STALLED, BusLink, GroupRead
from puppet.bus.unwrap import TurnUnwrapper, unwrap_period
from puppet.events import EventLog
from puppet.reading import Reading
from puppet.servo_models import REALTIME_TICK_WRAP, TICKS_PER_TURN, describe_hardware_error, model_named

READ_MODES = ("auto", "fast_sync_read", "sync_read")
DUPLICATE_PROBES = 6
"""Pings and single position reads that tell two servos on one id from a burst of bad CRCs."""
DUPLICATE_PINGS_OK = 5
"""Pings (of DUPLICATE_PROBES) that must answer for a duplicate id."""


BUS_UNHEARD = -1
"""Key of ``ServoReader._unproven_since`` while no servo has answered at all (no witness)."""


class ServoReader:
    """Reads the Present Position of a fixed list of servos, surviving bus faults.

    port:      port name ('/dev/ttyUSB0', '/dev/serial/by-id/...', a pty) or an open
               ``dynamixel_sdk.PortHandler``.
    servos:    {id: model name} ('XL330-M288', 'XL430-W250', 'AX-12A', ...), in reading order;
               all of one protocol (ValueError naming the servos of each otherwise).
    baud:      bits per second: one every servo's model can select (BusError naming those
               that cannot).
    latency_ms: the SDK's latency assumption (module global ``LATENCY_TIMER``), ms; None: the
               adapter's FTDI latency timer from sysfs where there is one, else 1.
    read_mode: 'auto' (fast sync read if all firmware supports it), 'fast_sync_read', 'sync_read'
               (Protocol 2.0; a Protocol 1.0 bus always reads as ``configure.p1_read_mode`` says).
    driven:    ids of actuators a driver owns (puppet.drive, through the ReaderProcess hook):
               read like the others, but setup, reconfiguration, recovery and auto-reboot never
               change their torque or reboot them (see ``configure_servo``).
    limits:    {id: (lo, hi)} continuous tick limits; a value outside is flagged, not taken.
    auto_reboot: reboot a sensor (never a driven servo) whose hardware error is latched (at most
               once per ``reboot_holdoff_s``).
    noise_threshold: jitter (ticks) above which a servo is flagged noisy.
    exact_within_s: a group read that took longer than this has an uncertain sampling time
               (a starved machine delays replies): its values are not used for the jitter.
    max_jump_ticks, max_speed_ticks_s: a change larger than max_jump + max_speed·dt between two
               consecutive readings is taken as a corrupt reply (held, flagged, re-read); in
               X-series ticks (4096 per turn), scaled to each model's ticks per turn.
    jump_window_s: only a good reading younger than this is a reference for that check.
    stall_limit_s: a servo unheard this long is booked failed even without a witness's proof.

    ``stalls``: timeouts not booked because the line showed them late or could not judge them
    (each logged as a ``late_reply`` event).
    """

    def __init__(
        self,
        port: str | dynamixel_sdk.PortHandler,
        servos: Mapping[int, str],
        *,
        baud: int = 1_000_000,
        latency_ms: int | None = None,
        read_mode: str = "auto",
        driven: Iterable[int] = (),
        limits: Mapping[int, tuple[int, int]] | None = None,
        auto_reboot: bool = True,
        missing_after: int = 3,
        duplicate_after: int = 3,
        probe_period_s: float = 0.05,
        health_period_s: float = 0.5,
        reconnect_period_s: float = 0.2,
        poll_block_s: float = 0.0002,
        noise_threshold: float = 6.0,
        exact_within_s: float = 0.004,
        max_jump_ticks: int = 1024,
        max_speed_ticks_s: float = 20000.0,
        jump_window_s: float = 0.1,
        reboot_holdoff_s: float = 2.0,
        stall_limit_s: float = 5.0,
    ):
        if not servos:
            raise ValueError("ServoReader: the servo map is empty")
        if read_mode not in READ_MODES:
            raise ValueError(f"ServoReader: read_mode {read_mode!r} not in {READ_MODES}")
        for dxl_id, name in servos.items():
            if not 0 <= int(dxl_id) <= 252:
                raise ValueError(f"ServoReader: servo id {dxl_id} outside 0..252")
            model_named(name)
        self.servos = {int(i): str(m) for i, m in servos.items()}
        self.protocol = bus_protocol(self.servos, "ServoReader: the servo map")
        check_baud(self.servos, baud, str(port) if isinstance(port, str) else port.getPortName())
        self.models = {i: model_named(m) for i, m in self.servos.items()}
        self.items = {i: m.items for i, m in self.models.items()}
        """{id: ControlItems}: where each servo's model keeps what the reader reads."""
        self.driven = frozenset(int(i) for i in driven)
        unknown = self.driven - set(self.servos)
        if unknown:
            raise ValueError(f"ServoReader: driven servos {sorted(unknown)} are not in the servo map")
        self.limits = {int(i): (int(lo), int(hi)) for i, (lo, hi) in (limits or {}).items()}
        self.link = BusLink(port, baud=baud, latency_ms=latency_ms, poll_block_s=poll_block_s,
                            protocol=self.protocol)
        self.read_mode_requested = read_mode
        self.read_mode = "sync_read"
        self.auto_reboot = auto_reboot
        self.noise_threshold = float(noise_threshold)
        self.exact_within_ns = int(exact_within_s * 1e9)
        self.max_jump_ticks = int(max_jump_ticks)
        self.max_speed_ticks_s = float(max_speed_ticks_s)
        self.jump_window_s = float(jump_window_s)
        self.reboot_holdoff_ns = int(reboot_holdoff_s * 1e9)
        self._last_reboot_ns: dict[int, int] = {}
        self.missing_after = missing_after
        self.duplicate_after = duplicate_after
        self.probe_period_ns = int(probe_period_s * 1e9)
        self.health_period_ns = int(health_period_s * 1e9)
        self.reconnect_period_ns = int(reconnect_period_s * 1e9)
        self.stall_limit_ns = int(stall_limit_s * 1e9)
        self.stalls = 0
        self._stalled = False           # this read() met a stalled line: spare further timeouts
        # id (BUS_UNHEARD: the whole bus, no witness) -> first unproven timeout in a row (ns)
        self._unproven_since: dict[int, int] = {}

        self.ids = np.array(list(self.servos), dtype=np.int64)
        self.ids.setflags(write=False)
        self._index = {int(i): k for k, i in enumerate(self.ids)}
        self._ticks = np.zeros(len(self.ids), dtype=np.int32)
        self._ok = np.zeros(len(self.ids), dtype=bool)
        self._late = np.zeros(len(self.ids), dtype=bool)  # held, nothing booked (Reading.late)
        self._prev = [0] * len(self.ids)          # last two good values and their times (ns),
        self._prev2 = [0] * len(self.ids)         # for jitter
        self._prev_t = [0] * len(self.ids)
        self._prev2_t = [0] * len(self.ids)
        self._run = [0] * len(self.ids)           # good readings in a row
        self.unwrap = {i: TurnUnwrapper(unwrap_period(m)) for i, m in self.models.items()}
        scale = {i: m.ticks_per_turn / TICKS_PER_TURN for i, m in self.models.items()}
        self._max_jump = {i: self.max_jump_ticks * f for i, f in scale.items()}
        self._max_speed = {i: self.max_speed_ticks_s * f for i, f in scale.items()}
        self.health = {i: hs.ServoHealth(i, m) for i, m in self.servos.items()}
        self.log = EventLog()
        self.report: SetupReport | None = None

        self._group: list[int] = list(self.servos)     # ids in the group read, map order
        self._plan: tuple | None = None  # (group, {id: Present Position item}, bulk ids)
        self._next_probe_ns: dict[int, int] = {}
        self._tick_seen: dict[int, tuple[int, int]] = {}  # id -> (realtime tick ms, host ns)
        self._next_health_ns = 0
        self._health_due = False
        self._port_up = False
        self._next_reconnect_ns = 0
        self.reads = 0

    # ---- setup ---------------------------------------------------------------------------
    def open(self, broadcast_ping: bool = False, strict: bool = False) -> SetupReport:
        """Open the port, find and check the servos, configure them, take a first reading.

        broadcast_ping: also list servos on the bus that the map lacks (costs ~0.8 s).
        strict: raise ServoMissing when a mapped servo does not answer (otherwise it is
                flagged and probed until it appears).
        Raises PortError (no port), ServoModelMismatch (map and bus disagree), ServoMissing
        when no servo of the map answers at all (a wrong port, baud rate or protocol).
        """
        self.link.open()
        self._port_up = True
        report = SetupReport()
        if self.link.latency_note:
            report.notes.append(self.link.latency_note)
        if broadcast_ping:
            found = self.link.broadcast_ping()
            report.unexpected = {i: m for i, (m, _) in found.items() if i not in self.servos}
        identify(self.link, self.servos, report)
        self._identify_again(report)
        if self.servos and not report.found:  # nothing to read: a wrong port, baud or protocol
            protocol = "1.0" if self.link.wire.p1 else "2.0"
            raise ServoMissing(report.missing, "ping", (
                f"no servo of the map answered on {self.link.port_name} at {self.link.baud} "
                f"bit/s (Protocol {protocol}, the rig's servos' protocol): check the power, "
                "the --baud and the servos' protocol (puppet scan --port PORT --baud all "
                "lists what answers)"))
        if report.missing and strict:
            raise ServoMissing(report.missing, "ping", f"on {self.link.port_name}")
        fast_ok = supports_fast_sync_read(self.servos, report.found)
        if self.link.wire.p1:
            self.read_mode = p1_read_mode(self.servos)
        elif self.read_mode_requested == "auto":
            self.read_mode = "fast_sync_read" if fast_ok else "sync_read"
        else:
            self.read_mode = self.read_mode_requested
        report.read_mode = self.read_mode
        for dxl_id in self.servos:
            if dxl_id in report.missing:
                self._mark_missing(dxl_id, ServoTimeout([dxl_id], "ping", "no answer at setup"))
                continue
            bits = self._configure_at_setup(dxl_id, report)
            if bits is None:
                continue
            if bits:
                report.hardware_errors[dxl_id] = bits
                self._on_hardware_error(dxl_id, bits)
        self.report = report
        self._next_health_ns = 0
        self.read()
        return report

    def _configure_at_setup(self, dxl_id: int, report: SetupReport) -> int | None:
        """Configure one servo (three tries; timeouts go on until the line proves the servo
        silent) -> its Hardware Error Status bits, or None when it failed (marked missing)."""
        tries = 0
        while True:
            try:
                configure_servo(self.link, dxl_id, dxl_id in self.driven, report.changes,
                                self.items[dxl_id])
                return self.link.hardware_error(dxl_id, self.items[dxl_id])
            except ServoError as exc:
                tries += 1
                if tries < 3:
                    continue
                if exc.deadline and not self._silence_proven(
                        dxl_id, time.monotonic_ns(), report.found, stalled=exc.line_stalled,
                        late=exc.reply_late):
                    continue
                self._mark_missing(dxl_id, exc)
                report.missing.append(dxl_id)
                return None

    def _identify_again(self, report: SetupReport) -> None:
        """Ping again each servo that did not answer at setup until the line proves it silent
        (or its timeouts stay unproven for ``stall_limit_s``): a starved machine must not make
        a servo missing. Only a ping that was sent and timed out can be proven silent."""
        for dxl_id in list(report.missing):
            while True:
                try:
                    self.link.ping(dxl_id)
                except ServoError as exc:
                    if not exc.deadline or self._silence_proven(
                            dxl_id, time.monotonic_ns(), report.found, stalled=exc.line_stalled):
                        break  # silent, or answering but not cleanly: missing, as identify found
                    continue
                again = SetupReport()
                identify(self.link, {dxl_id: self.servos[dxl_id]}, again)
                if dxl_id in again.found:
                    report.missing.remove(dxl_id)
                    report.found[dxl_id] = again.found[dxl_id]
                    break
        report.found = {i: report.found[i] for i in self.servos if i in report.found}

    def close(self) -> None:
        """Close the port (torque is left as configured)."""
        self.link.close()
        self._port_up = False

    def __enter__(self) -> ServoReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- per frame -----------------------------------------------------------------------
    def read(self) -> Reading:
        """One reading of every servo: t_ns (monotonic ns, taken just before the group read),
        ticks (k,) int32 continuous, ok (k,) bool. Never raises for bus faults."""
        self.reads += 1
        now = time.monotonic_ns()
        self._ok[:] = False
        self._late[:] = False
        self._stalled = False
        if not self._port_up and not self._reconnect(now):
            return self._reading(now)
        try:
            self._read_group(now)
            self._probe_missing(now)
            if self._health_due or now >= self._next_health_ns:
                self._check_health(now)
        except PortError as exc:
            self._port_lost(exc)
        except ServoError as exc:  # a bookkeeping transaction failed; the readings stand
            self.log.add("transaction_failed", exc.ids, str(exc))
        return self._reading(now)

    def read_clean(self, samples: int = 1, timeout_s: float = 2.0) -> Reading:
        """A reading where every servo is ok; with ``samples`` > 1 the per-servo median of that
        many clean readings (for zero-pose capture). ServoTimeout naming the servos that never
        read cleanly (else those of the last reading) when ``timeout_s`` runs out."""
        deadline = time.monotonic() + timeout_s
        clean: list[Reading] = []
        bad: set[int] = set()
        never = set(self.servos)
        while len(clean) < samples:
            reading = self.read()
            never -= {int(i) for i in reading.ids[reading.ok]}
            if reading.ok.all():
                clean.append(reading)
            else:
                bad = {int(i) for i in reading.ids[~reading.ok]}
            if time.monotonic() > deadline:
                raise ServoTimeout(never or bad or set(self.servos), "read_clean",
                                   f"{len(clean)} of {samples} clean readings in {timeout_s} s")
        ticks = np.median(np.stack([r.ticks for r in clean]), axis=0).round().astype(np.int32)
        return Reading(clean[-1].t_ns, self.ids, ticks, np.ones(len(self.ids), dtype=bool))

    def _reading(self, t_ns: int) -> Reading:
        return Reading(t_ns, self.ids, self._ticks.copy(), self._ok.copy(), late=self._late.copy())

    def _group_read(self, ids: list[int]) -> GroupRead:
        """Present Position of ``ids`` (the group) by the fastest transactions their models have
        (see the module docstring; ``BusLink.group_read``). Its plan is made once per group."""
        if self._plan is None or self._plan[0] != ids:
            self._plan = (list(ids), {i: self.items[i].present_position for i in ids},
                          [i for i in ids if self.models[i].bulk_read])
        _, items, bulk = self._plan
        fast = self.read_mode == "fast_sync_read"
        result = self.link.group_read(items, fast=fast, bulk=bulk)
        if fast and self._fast_unsupported(result):
            self.read_mode = "sync_read"
            self.log.add("fast_read_disabled", ids, "servos answered Fast Sync Read with an error")
            result = self.link.group_read(items, bulk=bulk)
        return result

    @staticmethod
    def _fast_unsupported(result: GroupRead) -> bool:
        """Fast Sync Read answered by a normal status with Instruction Error (old firmware)."""
        errs = {getattr(e, "error", 0) & 0x7F for e in result.failed.values()}
        return not result.values and errs == {0x02}

    def _read_group(self, now: int) -> None:
        if not self._group:
            return
        result = self._group_read(self._group)
        exact = time.monotonic_ns() - now <= self.exact_within_ns
        for dxl_id, error in result.errors.items():
            self._note_alert(dxl_id, error)
        for dxl_id, raw in result.values.items():
            implausible = self._implausible(dxl_id, raw, now)
            if implausible is None:
                self._accept(dxl_id, raw, now, exact)
            else:
                self._read_alone(dxl_id, implausible, now)
        for dxl_id, exc in result.failed.items():
            if dxl_id in result.alone:
                self._alone_failed(dxl_id, exc, now)
            else:
                self._read_alone(dxl_id, exc, now)

    def _read_alone(self, dxl_id: int, group_exc: ServoError, now: int) -> None:
        """Individual read of a servo the group read failed for (skipped, nothing booked, when
        this read already met a stalled line: its value held, late, not a fault)."""
        if self._stalled:
            self._late[self._index[dxl_id]] = True
            return
        try:
            raw, error = self.link.read_with_status(dxl_id, self.items[dxl_id].present_position)
        except ServoError as exc:
            self._alone_failed(dxl_id, exc, now)
            return
        self._note_alert(dxl_id, error)
        implausible = self._implausible(dxl_id, raw, now)
        if implausible is not None:
            self._failed(dxl_id, implausible, now)
            return
        self._accept(dxl_id, raw, now)

    def _alone_failed(self, dxl_id: int, exc: ServoError, now: int) -> None:
        """A servo's own read failed: booked once the failure is certain (see the docstring);
        until then its value is held as late (``Reading.late``), not a fault."""
        if self._stalled or exc.deadline and not self._silence_proven(
                dxl_id, now, stalled=exc.line_stalled, late=exc.reply_late):
            self._late[self._index[dxl_id]] = True
            return
        self._failed(dxl_id, exc, now)

    def _silence_proven(self, dxl_id: int, now: int, heard=None, stalled: bool = False,
                        late: bool = False) -> bool:
        """Whether a timeout of ``dxl_id`` is a proven silence (see the module doc): a witness
        (a servo that answered: in ``heard`` at setup, else ok in this reading or heard last)
        is asked for a read. False (counted in ``stalls``) when the line shows the reply was late or
        cannot judge, unless ``dxl_id``'s timeouts have gone unproven for ``stall_limit_s``.
        ``late``: a witness already showed this reply late (``ServoError.reply_late``): no second
        witness, which would find the line clean and call the servo silent."""
        witness = self._witness_for(dxl_id, heard)
        if late:
            verdict = LATE
        elif stalled or witness is None or heard is None and self._stalled:
            verdict = STALLED
        else:
            verdict = self.link.witness(witness)
        if verdict == SILENT:
            self._unproven_since.pop(dxl_id, None)
            return True
        self.stalls += 1
        self._stalled = verdict == STALLED
        # no servo ever answered: one wait for the whole silent bus, not one per servo (a
        # rig of 15 on a bus where nothing answers would wait 15 stall limits)
        key = dxl_id if witness is not None else BUS_UNHEARD
        since = self._unproven_since.setdefault(key, now)
        if now - since > self.stall_limit_ns:
            if key == dxl_id:
                del self._unproven_since[dxl_id]
            return True
        self.log.add("late_reply", [dxl_id], "the reply missed its deadline and the line shows it "
                     "on its way" if verdict == LATE else "the reply missed its deadline and the "
                     "line could not tell why (a starved host)")
        return False

    def _witness_for(self, dxl_id: int, heard=None) -> int | None:
        """A servo other than ``dxl_id`` that answered: one in ``heard`` (setup) or ok in this
        reading, else the one heard most recently; None when no other servo ever answered."""
        if heard is not None:
            return next((i for i in heard if i != dxl_id), None)
        best, best_ns = None, 0
        for k, other in enumerate(self.ids):
            other = int(other)
            if other == dxl_id:
                continue
            if self._ok[k]:
                return other
            h = self.health[other]
            if h.state == hs.OK and h.last_ok_ns > best_ns:
                best, best_ns = other, h.last_ok_ns
        return best

    def _implausible(self, dxl_id: int, raw: int, now: int) -> ServoCorrupt | None:
        """A jump no shaft can make between two readings (a reply with a valid CRC but wrong
        data, e.g. two servos' segments colliding) -> ServoCorrupt; None when plausible.
        Only checked against a good reading less than ``jump_window_s`` old."""
        h = self.health[dxl_id]
        value, _ = self.unwrap[dxl_id].peek(raw)  # a re-base must land near the last value too
        last = self.unwrap[dxl_id].last
        if last is None:
            return None
        dt_s = max(0.0, (now - h.last_ok_ns) / 1e9)
        if dt_s > self.jump_window_s:
            return None
        bound = self._max_jump[dxl_id] + self._max_speed[dxl_id] * dt_s
        if abs(value - last) <= bound:
            return None
        return ServoCorrupt([dxl_id], "read Present Position",
                            f"implausible jump {last} -> {value} ticks in {dt_s * 1e3:.1f} ms")

    def _probe_missing(self, now: int) -> None:
        """Probe at most one missing servo per frame, each at most every probe period."""
        for dxl_id, due in self._next_probe_ns.items():
            if now >= due:
                break
        else:
            return
        self._next_probe_ns[dxl_id] = now + self.probe_period_ns
        try:
            raw, error = self.link.read_with_status(dxl_id, self.items[dxl_id].present_position)
        except ServoError as exc:
            self._failed(dxl_id, exc, now)
            return
        self._returned(dxl_id, now)
        self._note_alert(dxl_id, error)
        self._accept(dxl_id, raw, now)

    # ---- per-servo bookkeeping -----------------------------------------------------------
    def _accept(self, dxl_id: int, raw: int, now: int, exact: bool = False) -> None:
        """Take ``raw`` as the servo's value at ``now``; ``exact``: that time is known to within
        ``exact_within_s`` (only such values feed the jitter estimate)."""
        h = self.health[dxl_id]
        if self.models[dxl_id].dead_zone_deg:
            top = self.models[dxl_id].max_position
            if not 0 < raw < top:  # no angle: the shaft may be anywhere in the dead zone
                if not h.dead_zone:
                    self.log.add("dead_zone", [dxl_id], f"Present Position {raw}: at an end of "
                                 f"its {self.servos[dxl_id]}'s 0..{top}, where the "
                                 f"{self.models[dxl_id].dead_zone_deg:.0f}° dead zone reads")
                h.dead_zone = True
                return
            h.dead_zone = False
        unwrapper = self.unwrap[dxl_id]
        value, offset = unwrapper.peek(raw)
        lo_hi = self.limits.get(dxl_id)
        if lo_hi is not None and not lo_hi[0] <= value <= lo_hi[1]:
            if not h.out_of_limits:
                self.log.add("out_of_limits", [dxl_id], f"{value} ticks outside {lo_hi[0]}..{lo_hi[1]}")
            h.out_of_limits = True
            h.last_error = ServoCorrupt([dxl_id], "read Present Position",
                                        f"{value} ticks outside limits {lo_hi[0]}..{lo_hi[1]}")
            return
        h.out_of_limits = False
        value, rebased = unwrapper.accept(raw)
        if rebased:
            h.rebases += 1
            self.log.add("rebased", [dxl_id], f"raw {raw}: turn offset now {unwrapper.offset} ticks")
        k = self._index[dxl_id]
        if exact:
            self._track_jitter(h, k, value, now)
        else:
            self._run[k] = 0
        self._ticks[k] = value
        self._ok[k] = True
        self._late[k] = False
        if h.state != hs.OK:
            self.log.add("servo_recovered", [dxl_id], f"was {h.state}")
            h.state = hs.OK
        h.consecutive_failures = 0
        h.corrupt_in_a_row = 0
        h.last_ok_ns = now
        self._unproven_since.pop(dxl_id, None)
        self._unproven_since.pop(BUS_UNHEARD, None)  # the bus answers

    def _track_jitter(self, h: hs.ServoHealth, k: int, value: int, t_ns: int) -> None:
        """Running mean of the error of a linear prediction from the last two good readings
        (extrapolated to this reading's time, so uneven read intervals during fast motion are
        not taken for noise): zero at rest or in steady motion, about the noise amplitude for a
        jittering encoder."""
        if self._run[k] >= 2 and self._prev_t[k] > self._prev2_t[k]:
            ratio = (t_ns - self._prev_t[k]) / (self._prev_t[k] - self._prev2_t[k])
            d2 = abs(value - self._prev[k] - (self._prev[k] - self._prev2[k]) * ratio)
            h.jitter += 0.05 * (min(d2, 4 * self.noise_threshold) - h.jitter)
            noisy = h.jitter > self.noise_threshold
            if noisy != h.noisy:
                h.noisy = noisy
                self.log.add("noisy" if noisy else "quiet", [h.id],
                             f"jitter {h.jitter:.1f} ticks (threshold {self.noise_threshold})")
        self._prev2[k], self._prev[k] = self._prev[k], value
        self._prev2_t[k], self._prev_t[k] = self._prev_t[k], t_ns
        self._run[k] += 1

    def _failed(self, dxl_id: int, exc: ServoError, now: int) -> None:
        """Book one failed read. Timeouts in a row -> MISSING; corrupt replies in a row ->
        DUPLICATE (ping answers, position reads never do: see _collides) or CORRUPT; both leave the group read and are probed.
        Error-status replies -> FAILING (they cost the group nothing)."""
        h = self.health[dxl_id]
        self._run[self._index[dxl_id]] = 0
        self._late[self._index[dxl_id]] = False  # booked: a fault now
        h.failures += 1
        h.consecutive_failures += 1
        h.last_error = exc
        h.corrupt_in_a_row = h.corrupt_in_a_row + 1 if isinstance(exc, ServoCorrupt) else 0
        if h.state in (hs.MISSING, hs.DUPLICATE, hs.CORRUPT):
            return
        if h.corrupt_in_a_row >= self.duplicate_after:
            h.state = hs.DUPLICATE if self._collides(dxl_id) else hs.CORRUPT
            self._leave_group(dxl_id, now)
            if h.state == hs.DUPLICATE:
                self.log.add("duplicate_id", [dxl_id], f"{h.corrupt_in_a_row} corrupt replies in a row while "
                             f"ping answers: replies collide, two servos answer to id {dxl_id}?")
            else:
                self.log.add("corrupt", [dxl_id], f"{h.corrupt_in_a_row} corrupt replies in a row: {exc}")
        elif isinstance(exc, ServoTimeout) and h.consecutive_failures >= self.missing_after:
            self._mark_missing(dxl_id, exc)
        elif h.state == hs.OK or h.state == hs.PORT_DOWN:
            h.state = hs.FAILING
            self.log.add("servo_failed", [dxl_id], str(exc))

    def _collides(self, dxl_id: int) -> bool:
        """True when the replies look like two servos answering to one id: their ping replies
        are identical (same model) and survive the collision, their position replies differ and
        never do. A burst of bad CRCs spoils both alike, so ping must answer at least
        DUPLICATE_PINGS_OK of DUPLICATE_PROBES tries and no position read may (a CRC burst that
        passes some of its replies is taken for a duplicate at most about 0.1 % of the time)."""
        pings = reads = 0
        for _ in range(DUPLICATE_PROBES):
            try:
                self.link.ping(dxl_id)
                pings += 1
            except ServoError:
                pass
            try:
                self.link.read_with_status(dxl_id, self.items[dxl_id].present_position)
                reads += 1
            except ServoError:
                pass
        return pings >= DUPLICATE_PINGS_OK and reads == 0

    def _mark_missing(self, dxl_id: int, exc: ServoError) -> None:
        h = self.health[dxl_id]
        h.state = hs.MISSING
        h.last_error = exc
        self._leave_group(dxl_id, time.monotonic_ns())
        self.log.add("servo_missing", [dxl_id], str(exc))

    def _leave_group(self, dxl_id: int, now: int) -> None:
        if dxl_id in self._group:
            self._group.remove(dxl_id)
        self._next_probe_ns[dxl_id] = now + self.probe_period_ns

    def _returned(self, dxl_id: int, now: int) -> None:
        """A probed servo answered again: reconfigure it (it may have rebooted), rejoin the group."""
        self._next_probe_ns.pop(dxl_id, None)
        self._group = [i for i in self.servos if i in self._group or i == dxl_id]
        self._reconfigure(dxl_id, "answered again")
        self._health_due = True  # its Realtime Tick tells whether it rebooted meanwhile

    def _reconfigure(self, dxl_id: int, why: str) -> None:
        changes: list = []
        try:
            configure_servo(self.link, dxl_id, dxl_id in self.driven, changes, self.items[dxl_id])
        except ServoError as exc:
            self.health[dxl_id].last_error = exc
            self.log.add("reconfigure_failed", [dxl_id], f"{why}: {exc}")
            return
        self.log.add("reconfigured", [dxl_id],
                     f"{why}: " + (", ".join(f"{c.item} {c.old}->{c.new}" for c in changes) or "no change"))

    def _note_alert(self, dxl_id: int, error: int) -> None:
        alert = bool(error & ALERT_BIT)
        h = self.health[dxl_id]
        if alert and not h.alert:
            self._health_due = True
        h.alert = alert

    # ---- periodic health: hardware errors and reboots ------------------------------------
    def _check_health(self, now: int) -> None:
        self._health_due = False
        self._next_health_ns = now + self.health_period_ns
        ids = list(self._group)
        if not ids:
            return
        if self.link.wire.p1:  # no such items: the bits of each servo's latest status
            for dxl_id in ids:
                self._on_hardware_error(dxl_id, self.link.hardware_bits.get(dxl_id, 0))
            return
        for item, some in self._by_item(ids, "hardware_error_status").items():
            for dxl_id, bits in self.link.sync_read(some, item).values.items():
                self._on_hardware_error(dxl_id, bits)
        for item, some in self._by_item(ids, "realtime_tick").items():
            t0 = time.monotonic_ns()
            ticks = self.link.sync_read(some, item)
            t1 = time.monotonic_ns()
            for dxl_id, tick in ticks.values.items():
                self._check_tick(dxl_id, tick, t0, t1)

    def _by_item(self, ids: list[int], name: str) -> dict:
        """{Item: ids} of the servos of ``ids`` whose model has the item ``name`` (a field of
        ``ControlItems``), one entry per address."""
        out: dict = {}
        for dxl_id in ids:
            item = getattr(self.items[dxl_id], name)
            if item is not None:
                out.setdefault(item, []).append(dxl_id)
        return out

    def _on_hardware_error(self, dxl_id: int, bits: int) -> None:
        """Book Hardware Error Status ``bits``; reboot a sensor with a latched error when
        ``auto_reboot`` allows (again after the hold-off if it stays latched)."""
        h = self.health[dxl_id]
        if bits != h.hardware_error:
            if bits:
                self.log.add("hardware_error", [dxl_id],
                             f"Hardware Error Status 0x{bits:02x}: {describe_hardware_error(bits)}")
            else:
                self.log.add("hardware_error_cleared", [dxl_id],
                             f"was {describe_hardware_error(h.hardware_error)}")
            h.hardware_error = bits
        if not bits or not self.auto_reboot or dxl_id in self.driven or self.link.wire.p1:
            return  # (Protocol 1.0 has no Reboot: the bits clear with their cause)
        now = time.monotonic_ns()
        last = self._last_reboot_ns.get(dxl_id)
        if last is None or now - last > self.reboot_holdoff_ns:
            self._last_reboot_ns[dxl_id] = now
            self.reboot(dxl_id)

    def _check_tick(self, dxl_id: int, tick: int, t_ns: int, t_reply_ns: int) -> None:
        """A Realtime Tick (ms, wraps at 32768) behind its expected value means a reboot.

        The servo sampled ``tick`` between the request (``t_ns``) and the reply (``t_reply_ns``);
        a loaded machine can hold a reply long, so the tick is expected to have advanced at
        least from the previous reply's time to this request's, never more."""
        seen = self._tick_seen.get(dxl_id)
        self._tick_seen[dxl_id] = (tick, t_reply_ns)
        if seen is None:
            return
        elapsed_ms = (t_ns - seen[1]) / 1e6
        if elapsed_ms >= REALTIME_TICK_WRAP / 2:
            return  # too long ago to tell a wrap from a reboot
        expected = (seen[0] + elapsed_ms) % REALTIME_TICK_WRAP
        behind = (expected - tick) % REALTIME_TICK_WRAP
        if behind > REALTIME_TICK_WRAP / 2:
            behind -= REALTIME_TICK_WRAP
        if behind > max(100.0, 0.25 * elapsed_ms):
            h = self.health[dxl_id]
            h.reboots += 1
            self.log.add("rebooted", [dxl_id], f"Realtime Tick {tick} ms, expected about {expected:.0f}")
            self._reconfigure(dxl_id, "rebooted")

    def reboot(self, dxl_id: int) -> None:
        """Send Reboot to one sensor (clears a latched hardware error). Its position re-bases;
        the reader unwraps it. Failures are logged, never raised (PortError aside). ValueError
        for a driven servo: a reboot turns its torque off, which only its driver decides."""
        if dxl_id in self.driven:
            raise ValueError(f"ServoReader: servo {dxl_id} is driven: only its driver reboots it")
        try:
            self.link.reboot(dxl_id)
        except ServoError as exc:
            self.log.add("reboot_failed", [dxl_id], str(exc))
            return
        self.log.add("reboot_sent", [dxl_id], describe_hardware_error(self.health[dxl_id].hardware_error))
        self.health[dxl_id].reboots += 1
        self._tick_seen.pop(dxl_id, None)
        self._reconfigure(dxl_id, "after reboot")

    # ---- port loss and recovery ----------------------------------------------------------
    def _port_lost(self, exc: PortError) -> None:
        self._port_up = False
        self.link.close()
        self._ok[:] = False
        self._late[:] = False
        self._run = [0] * len(self.ids)
        for h in self.health.values():
            h.last_error = exc
            if h.state == hs.OK or h.state == hs.FAILING:
                h.state = hs.PORT_DOWN
        self._next_reconnect_ns = time.monotonic_ns() + self.reconnect_period_ns
        self.log.add("port_lost", (), str(exc))

    def _reconnect(self, now: int) -> bool:
        if now < self._next_reconnect_ns:
            return False
        self._next_reconnect_ns = now + self.reconnect_period_ns
        try:
            self.link.rebuild()
            for dxl_id in self._group:
                self._reconfigure(dxl_id, "port restored")
        except PortError:
            self.link.close()
            return False
        self._port_up = True
        self._tick_seen.clear()
        self._health_due = True
        self.log.add("port_restored", (), self.link.port_name)
        return True

    # ---- views ---------------------------------------------------------------------------
    @property
    def port_up(self) -> bool:
        return self._port_up

    @property
    def group(self) -> tuple[int, ...]:
        """Ids in the group read now (the others are missing or colliding and being probed)."""
        return tuple(self._group)
