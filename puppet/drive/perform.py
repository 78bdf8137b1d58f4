"""A take performed on the puppet's servos, with no jerk, no runaway and torque off on every
way out.

Sequence: setup (torque off; see ``servos.DriveBus.prepare``) -> Goal Position := Present
Position -> a slow start profile -> torque on -> Bus Watchdog set to a few loop periods ->
countdown (unless ``yes``) -> a slow move to the take's first pose, waited for until every
servo reports it has arrived (Moving 0, Moving Status in-position) -> playback: each cycle one
Sync Write of goals then one Sync Read of Moving .. Present Temperature -> stop.

Health watchdog while torque is on: every cycle (the state read) Present Temperature against
a host limit below the servo's own, Present Current (Present Load on a model that senses no
current) against a host cap on sustained current (``health.CurrentTemperatureStop``, caps from
each servo's limits through the model table), the alert bit of each status (then Hardware
Error Status is read to name the error), servos that stop answering; every ``WATCHDOG_CHECK_CYCLES`` cycles the Bus Watchdog items (-1 = it
tripped). Any of these stops the performance naming the servo and the reading, with two
tolerances for a busy host, where one late reply must cost one cycle, not the performance:
a servo stops it only after ``READ_FAILURES_TO_STOP`` cycles in a row without a usable reading
and only if it then fails a read of its own too (a Fast Sync Read fails as a whole for one
silent servo: the servos that do not answer alone are named); a tripped Bus Watchdog (the host
or the line stalled past its period) is re-armed, goal := present and eased back at the start
speed, and stops it only when ``WATCHDOG_TRIPS_TO_STOP`` checks in a row find it tripped. A
goal write not sent because the line was stalled costs that cycle (its goals go with the next).

Stop (end of take, SIGINT, SIGTERM, bus error, any exception): torque off by one Sync Write
with no reply, then servo by servo, then read back; see ``DriveBus.torque_off``. A kill that no
``finally`` sees (SIGKILL, a hang-up, a crash in native code): the torque guardian, a child
process started and waited for before the port opens, opens the port
once this process is gone and does the same stop (``puppet.drive.guardian``); only a kill of
both at once leaves the servos to their Bus Watchdog. A port lost
mid-performance (an adapter pulled) is tried again for ``PORT_RETRY_S``: if it comes back,
torque goes off as above (the performance does not resume); if not, the error says torque may
still be on (the Bus Watchdog stops the servos) and names ``puppet release``.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from puppet import limits
from puppet.bus.errors import BusError, PortError, ServoCorrupt, ServoTimeout
from puppet.bus.link import BusLink
from puppet.bus.port_lock import PortInUse
from puppet.drive import items as it
from puppet.drive.errors import DriveError, HealthStop
from puppet.drive.goals import GoalShaper, TakeGoals
from puppet.drive.guardian import Guardian
from puppet.drive.health import (CURRENT_FRACTION, CURRENT_SUSTAIN_S, TEMPERATURE_CAP_C,
                                 TEMPERATURE_MARGIN_C, CurrentTemperatureStop)
from puppet.drive.servos import DriveBus
from puppet.events import HELD_READING
from puppet.histogram import Histogram
from puppet.servo_models import describe_hardware_error, protocol_of
from puppet.session.signals import Signals

WATCHDOG_CHECK_CYCLES = 10
"""The Bus Watchdog items are read every this many cycles (the state read is every cycle)."""
READ_FAILURES_TO_STOP = 10
"""Consecutive cycles a servo may go without a usable reading (or the goals stay unsent on a
stalled line) before the performance stops, if the servo then fails a read of its own too."""
RESCUES_TO_STOP = 3
"""Times in a row the servos of a failing group read all answer alone (no full reading in
between) before the performance stops anyway: the health checks need the group read."""
WATCHDOG_TRIPS_TO_STOP = 10
"""Watchdog checks in a row (one every WATCHDOG_CHECK_CYCLES cycles) that find a servo's Bus
Watchdog tripped before the performance stops; each earlier trip is re-armed. A host (or, on
hw_sim, a simulator) starved for more than the watchdog period trips it again and again on a
loaded machine: that costs the servo a slow ease back each time, not the performance."""
PORT_RETRY_S = 2.0
"""How long a port lost mid-performance is tried again (every ``PORT_RETRY_PERIOD_S``) to turn
torque off."""
PORT_RETRY_PERIOD_S = 0.1
NOTICE_REPEAT_S = 5.0
"""A condition said once (a Bus Watchdog trip, a stalled loop) is said again at most this often,
with how many times it came back since and on which servos (``_Notices``)."""


MAX_REPLAY_S = 600.0
"""Longest replay (take play time / speed, one pass) performed without ``yes`` (--yes): a longer
one is refused before the port opens, so a wrong take or speed does not drive the puppet for an
hour unattended."""


@dataclass
class PerformOptions:
    """How to perform.

    speed, rate_hz and watchdog_ms: within puppet.limits SPEED, GOAL_RATE_HZ, WATCHDOG_MS (else
    refused before anything opens). speed: take time per wall second. loop: repeat the take. yes: no countdown, and a replay
    longer than MAX_REPLAY_S is performed (else refused).
    watchdog: set the servos' Bus Watchdog (False: --no-watchdog). rate_hz: goal writes per
    second. watchdog_ms: Bus Watchdog period, ms (rounded up to 20 ms units; at least three
    loop periods). start_speed_deg_s / start_accel_deg_s2: the slow start profile (joint
    degrees of a direct-drive servo). max_speed_deg_s: the per-cycle rate limit of goals and
    the playback profile. temperature_margin_c: host limit = servo limit - margin, at most
    temperature_cap_c. current_fraction / current_sustain_s: host cap on sustained current (or
    load), see ``puppet.drive.health``.
    countdown_s: seconds of countdown. arrive_timeout_s: extra time allowed to arrive.
    baud, latency_ms: the link (see BusLink).
    key: perform only this key of a shot (``puppet keys goto``): the start eases the servos to
    it and waits until they are there, then torque goes off (a one-pose take).
    """

    speed: float = 1.0
    loop: bool = False
    yes: bool = False
    watchdog: bool = True
    rate_hz: float = 100.0
    watchdog_ms: float = 100.0
    start_speed_deg_s: float = 30.0
    start_accel_deg_s2: float = 200.0
    max_speed_deg_s: float = 360.0
    temperature_margin_c: float = TEMPERATURE_MARGIN_C
    temperature_cap_c: float = TEMPERATURE_CAP_C
    current_fraction: float = CURRENT_FRACTION
    current_sustain_s: float = CURRENT_SUSTAIN_S
    countdown_s: int = 3
    arrive_timeout_s: float = 10.0
    baud: int = 1_000_000
    latency_ms: int | None = None
    key: int | None = None


@dataclass
class PerformReport:
    """What a performance did. Per-servo dicts are keyed by servo id."""

    stop_reason: str = "not started"
    cycles: int = 0
    playback_s: float = 0.0
    rate_hz: float = 0.0
    start_profile_deg_s: float = 0.0
    start_max_speed_deg_s: dict = field(default_factory=dict)
    tracking_median_deg: float | None = None
    tracking_p99_deg: float | None = None
    clamped: dict = field(default_factory=dict)
    rate_limited: dict = field(default_factory=dict)
    flagged: dict = field(default_factory=dict)
    take_damage: str | None = None   # what reading the take skipped or cut (TakeReader.recovery)
    changes: list = field(default_factory=list)
    recovered: list = field(default_factory=list)
    rearmed: dict = field(default_factory=dict)
    unsent_cycles: int = 0
    torque_after: dict = field(default_factory=dict)
    log: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return asdict(self)

    def text(self) -> str:
        lines = [f"stopped: {self.stop_reason}",
                 f"cycles: {self.cycles} in {self.playback_s:.2f} s ({self.rate_hz:.0f} Hz)"]
        if self.tracking_median_deg is not None:
            lines.append(f"tracking: median {self.tracking_median_deg:.2f} deg, "
                         f"p99 {self.tracking_p99_deg:.2f} deg")
        if self.take_damage:
            lines.append(f"take: {self.take_damage}")
        if self.rearmed:
            lines.append(f"Bus Watchdog re-armed after a stall (times per servo): {self.rearmed}")
        for name, label in (("clamped", "clamped"), ("rate_limited", "rate limited"), ("flagged", HELD_READING)):
            table = getattr(self, name)
            if table:
                per_servo = ", ".join(f"servo {i} {n}" for i, n in sorted(table.items()))
                lines.append(f"{label} (cycles or readings per servo): {per_servo}")
        if not self.torque_after:
            lines.append("torque: never turned on")
            return "\n".join(lines)
        off = [i for i, v in self.torque_after.items() if v == 0]
        unknown = {i: v for i, v in self.torque_after.items() if v != 0}
        lines.append(f"torque off (read back): servos {off}"
                     + (f"; NOT confirmed: {unknown}" if unknown else ""))
        return "\n".join(lines)


class _Notices:
    """The performance's repeated conditions, merged: one line per condition naming its servos
    (a trip of 15 watchdogs is one line, not 15), then at most one line per ``NOTICE_REPEAT_S``
    while it comes back, with its count since, and at the stop a line with its count in all.
    Bounded: one entry per condition (a fixed set of texts)."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self.say = say
        self.seen: dict[str, dict] = {}

    def add(self, condition: str, ids=(), detail: str = "") -> None:
        """``condition``: a fixed text, ``{servos}`` where the servos go; it happened on
        ``ids`` (none: on the host); ``detail``: this time's particulars (said only when the
        line is)."""
        ids = sorted(int(i) for i in ids)
        now = time.monotonic()
        entry = self.seen.setdefault(condition, {"times": 0, "unsaid": 0, "ids": set(),
                                                 "said_at": None})
        entry["times"] += 1
        entry["ids"].update(ids)
        if entry["said_at"] is not None and now - entry["said_at"] < NOTICE_REPEAT_S:
            entry["unsaid"] += 1
            return
        again = (f" ({entry['unsaid']} more times since the last such line)"
                 if entry["unsaid"] else "")
        self.say(condition.format(servos=_servos(ids)) + detail + again)
        entry["unsaid"], entry["said_at"] = 0, now

    def close(self) -> None:
        """Say each condition that came back after its last line: its count and servos in all."""
        for condition, entry in self.seen.items():
            if entry["unsaid"]:
                self.say(condition.format(servos=_servos(sorted(entry["ids"])))
                         + f": {entry['times']} times in all")
                entry["unsaid"] = 0


def _servos(ids) -> str:
    """'servos [1, 2]', 'servo 3', or 'the host' (no servo)."""
    return "the host" if not ids else f"servo {ids[0]}" if len(ids) == 1 else f"servos {ids}"


class _Stopped(Exception):
    """A signal asked the performance to stop (internal)."""


def perform(rig, reader, port: str, options: PerformOptions | None = None,
            log: Callable[[str], None] | None = None, on_phase: Callable[[str], None] | None = None
            ) -> PerformReport:
    """Perform the take open in ``reader`` (TakeReader) on ``rig``'s servos at ``port``.

    log: one line per event (changes, recoveries, countdown, failures); on_phase: called with
    'setup', 'start', 'playback', 'stop' as they begin. Returns the PerformReport of a
    performance that ended at the end of the take or by a signal; raises DriveError (its
    ``report`` attached, torque already off) for anything else.
    """
    opts = options or PerformOptions()
    for name, bound in (("speed", limits.SPEED), ("rate_hz", limits.GOAL_RATE_HZ),
                        ("watchdog_ms", limits.WATCHDOG_MS)):
        if not bound.holds(getattr(opts, name)):  # nan speed: a performance that never ends
            raise DriveError(f"{name} {bound.problem(getattr(opts, name))}")
    report = PerformReport()
    lines = report.log

    def say(text: str) -> None:
        lines.append(text)
        if log is not None:
            log(text)

    phase = on_phase or (lambda _p: None)
    notices = _Notices(say)
    if opts.watchdog:  # refused before anything moves: a model with no Bus Watchdog
        from puppet.rig.servo_map import check_bus_watchdogs

        check_bus_watchdogs(rig.servo_map.servos, rig.servo_map.path)
    goals = TakeGoals.from_take(reader, rig.servo_map, key=opts.key)
    report.flagged = dict(goals.flagged)
    # Everything wrong with the take is said before the port opens (torque on comes later).
    report.take_damage = reader.recovery
    if reader.recovery is not None:
        say(f"warning: {reader.path}: {reader.recovery}")
    if goals.flagged:
        held = ", ".join(f"servo {i} {n}" for i, n in sorted(goals.flagged.items()))
        say(f"{HELD_READING} in the take (those servos hold their last good value): {held}")
    replay_s = goals.duration_s / opts.speed
    if replay_s > MAX_REPLAY_S and not opts.yes:
        raise DriveError(f"{reader.path}: the replay would last {replay_s:.0f} s at speed "
                         f"{opts.speed:g}, over {MAX_REPLAY_S:.0f} s; give --yes to perform it")
    servo_map = rig.servo_map
    ids = [int(i) for i in servo_map.ids]
    link = BusLink(port, baud=opts.baud, latency_ms=opts.latency_ms,
                   protocol=protocol_of(servo_map.models))
    bus = DriveBus(link, ids, dict(servo_map.models), say)
    guardian = Guardian(port, dict(servo_map.models), baud=opts.baud, latency_ms=opts.latency_ms,
                        who="perform" if opts.key is None else "keys goto")
    torque_may_be_on = False
    error: BaseException | None = None
    with Signals() as signals:
        def check_signal() -> None:
            if signals.stop:
                raise _Stopped(signals.signal_name)
        try:
            guardian.start()
            guardian.wait_ready()  # before the port: its start competes with no bus setup
            link.open()
            # From here every way out turns torque off: a servo may still hold torque from an
            # earlier run (stopped by its watchdog) until setup reaches it.
            torque_may_be_on = True
            phase("setup")
            bus.prepare(opts.watchdog)
            report.changes = [f"servo {c.id}: {c.item} {c.old} -> {c.new}" for c in bus.changes]
            report.recovered = list(bus.recovered)
            check_signal()
            start_pose = _start(bus, goals, opts, report, say, check_signal, phase, notices)
            _playback(bus, goals, servo_map, start_pose, opts, report, say, check_signal, phase,
                      notices)
            report.stop_reason = "end of take"
        except _Stopped as stop:
            report.stop_reason = f"stopped by {stop}"
        except PortError as err:
            report.stop_reason = f"bus error: {err}"
            error = err
        except BaseException as err:  # noqa: BLE001 - every way out turns torque off, then re-raises
            report.stop_reason = f"{type(err).__name__}: {err}"
            error = err
        finally:
            if torque_may_be_on:  # first, before anything that could fail
                if isinstance(error, PortError) and _reopen(link):
                    say(f"the port came back within {PORT_RETRY_S:.0f} s: turning torque off")
                report.torque_after = bus.torque_off()
                if isinstance(error, PortError) and any(v is None for v in report.torque_after.values()):
                    say(f"the port is gone: the servos' Bus Watchdog stops them "
                        f"({opts.watchdog_ms:.0f} ms after the last frame)" if opts.watchdog
                        else "the port is gone and --no-watchdog was given: the servos keep their last goal")
            link.close()
            notices.close()
            gone = guardian.stand_down()
            if gone:
                say(gone)
            phase("stop")
    if error is not None:
        if isinstance(error, PortInUse):  # another program's port: nothing was touched
            raise error
        if isinstance(error, DriveError):
            error.report = report
            raise error
        if isinstance(error, (BusError,)):
            if not torque_may_be_on:
                done = "torque never went on"
            elif report.torque_after and set(report.torque_after.values()) == {0}:
                done = "torque off"
            elif isinstance(error, PortError):
                done = (f"the port did not come back within {PORT_RETRY_S:.0f} s: torque may still be "
                        "on" + (f" until the Bus Watchdog stops the servos ({opts.watchdog_ms:.0f} ms)"
                                if opts.watchdog else "")
                        + f"; when the adapter is back, `puppet release --port {port}` turns it off")
            else:
                done = (f"torque off NOT confirmed on every servo; `puppet release --port {port}` "
                        "turns it off")
            raise DriveError(f"performance stopped ({done}): {error}", report) from error
        raise error
    return report


def _reopen(link: BusLink) -> bool:
    """Try the lost port again for PORT_RETRY_S -> whether it is open again."""
    deadline = time.monotonic() + PORT_RETRY_S
    while True:
        try:
            link.rebuild()
            return True
        except PortError:
            if time.monotonic() > deadline:
                return False
            time.sleep(PORT_RETRY_PERIOD_S)


def _watchdog_units(opts: PerformOptions) -> int:
    period_ms = 1000.0 / opts.rate_hz
    ms = max(opts.watchdog_ms, 3 * period_ms)
    return max(1, min(127, math.ceil(ms / (it.WATCHDOG_UNIT_S * 1000.0))))


def _start(bus: DriveBus, goals: TakeGoals, opts, report, say, check_signal, phase,
           notices: _Notices) -> np.ndarray:
    """Goal := present, slow profile, torque on, watchdog, countdown, slow move to the first
    pose; returns that pose, (k,) goal ticks."""
    phase("start")
    present = _read_positions(bus)
    lo, hi = _limits(bus, goals)
    for n, dxl_id in enumerate(bus.ids):
        info = bus.setup[dxl_id]
        if info.mode != it.POSITION_MODE and not lo[n] - 2048 <= present[n] <= hi[n] + 2048:
            raise DriveError(
                f"servo {dxl_id}: present position {present[n]:.0f} is outside the rig's range "
                f"{lo[n]:.0f}..{hi[n]:.0f} ticks in {it.POSITION_MODES[info.mode]} mode (the turn "
                "count is lost at power-up): turn the joint into range by hand")
    bus.write_all("goal_position", present)
    unit = bus.velocity_unit_deg_s
    start_units = np.clip(np.rint(opts.start_speed_deg_s / unit), 1, bus.speed_max)
    accel_units = max(1, round(opts.start_accel_deg_s2 / it.ACCEL_UNIT_DEG_S2))
    report.start_profile_deg_s = float((start_units * unit).max())
    bus.write_all("moving_speed", start_units)   # never 0 (= full speed) for the start
    bus.write_all("profile_acceleration", accel_units)  # (X layout only)
    bus.write_all("torque_enable", 1)
    bus.check_torque(1)
    if opts.watchdog:
        units = _watchdog_units(opts)
        bus.write_all("bus_watchdog", units)
        say(f"Bus Watchdog {units * 20} ms on every servo")
    first = np.clip(np.where(np.isnan(goals.goals[0]), present, goals.goals[0]), lo, hi)
    distance = float(goals.units.servo_degrees(first - present).max())
    if not opts.yes:
        say(f"moving to the first pose ({distance:.0f} deg at most, "
            f"{report.start_profile_deg_s:.0f} deg/s) in {opts.countdown_s}")
        for n in range(opts.countdown_s, 0, -1):
            say(f"{n}...")
            _wait(1.0, bus, opts, check_signal)
    bus.write_all("goal_position", np.round(first))  # sent again while the line is stalled
    timeout = distance / max(report.start_profile_deg_s, 1e-3) * 3 + opts.arrive_timeout_s
    deadline = time.monotonic() + timeout
    speeds = np.zeros(len(bus.ids))

    def rearm(n: int) -> None:  # a stall tripped its watchdog: back to the slow move
        bus.rearm(bus.ids[n], _watchdog_units(opts))
        bus.write(bus.ids[n], "goal_position", int(round(first[n])))

    health = _Health(bus, opts, on_trip=lambda tripped: _rearm_all(tripped, rearm, bus, report,
                                                                   notices))
    while True:
        check_signal()
        state = bus.read_state()
        health.check(state, 1.0 / opts.rate_hz)
        np.maximum(speeds, np.where(state.ok, np.abs(state.velocity), 0), out=speeds)
        if (state.ok.all() and not state.moving.any()
                and (state.moving_status & it.MOVING_STATUS_IN_POSITION).all()):
            break
        if time.monotonic() > deadline:
            late = [i for i, m, s in zip(bus.ids, state.moving, state.moving_status)
                    if m or not s & it.MOVING_STATUS_IN_POSITION]
            raise DriveError(f"servos {late} did not reach the first pose within {timeout:.0f} s")
        _wait(1.0 / opts.rate_hz, bus, opts, check_signal, keepalive=False)
    report.start_max_speed_deg_s = {i: float(v * u) for i, v, u in zip(bus.ids, speeds, unit)}
    play_units = np.clip(np.rint(opts.max_speed_deg_s / unit), 1, bus.speed_max)
    bus.write_all("profile_acceleration", 0)
    bus.write_all("moving_speed", play_units)
    return first


def _wait(seconds: float, bus: DriveBus, opts, check_signal, keepalive: bool = True) -> None:
    """Wait ``seconds``, still talking to the servos often enough for their Bus Watchdog."""
    end = time.monotonic() + seconds
    step = min(1.0 / opts.rate_hz, opts.watchdog_ms / 3000.0)
    while True:
        check_signal()
        left = end - time.monotonic()
        if left <= 0:
            return
        if keepalive:
            bus.read_state()
        time.sleep(min(step, left))


REARMED = ("Bus Watchdog tripped on {servos} (the host or the line stalled past its period): "
           "re-armed, easing back from the present position")
STALLED = "warning: the goal frames stalled ({servos} loop)"
REARM_FAILED = "re-arming the Bus Watchdog of {servos} failed (the next check tries again)"


def _rearm_all(tripped: list[int], rearm: Callable[[int], None], bus: DriveBus,
               report: PerformReport, notices: _Notices) -> None:
    """Re-arm each tripped servo (indices) with ``rearm``; one line for those re-armed, one
    for those that failed (``_Notices``)."""
    done, failed, why = [], [], ""
    for n in tripped:
        dxl_id = bus.ids[n]
        try:
            rearm(n)
        except (ServoTimeout, ServoCorrupt) as err:  # still tripped: the next check tries again
            failed.append(dxl_id)
            why = why or f" ({err})"
            continue
        done.append(dxl_id)
        report.rearmed[dxl_id] = report.rearmed.get(dxl_id, 0) + 1
    if done:
        notices.add(REARMED, done)
    if failed:
        notices.add(REARM_FAILED, failed, why)


def _read_positions(bus: DriveBus) -> np.ndarray:
    """Present Position of every servo (one read each, so that none is missing)."""
    return np.array([bus.read(i, "present_position") for i in bus.ids], float)


def _limits(bus: DriveBus, goals: TakeGoals) -> tuple[np.ndarray, np.ndarray]:
    """(k,) goal-tick limits: the rig's joint limits within the servo's own position limits."""
    lo, hi = goals.lo.copy(), goals.hi.copy()
    for n, dxl_id in enumerate(bus.ids):
        info = bus.setup[dxl_id]
        if info.lo is not None:
            lo[n] = max(lo[n], info.lo)
            hi[n] = min(hi[n], info.hi)
    return lo, hi


class _Health:
    """The host-side health watchdog over each cycle's state (see the module docstring).

    on_trip: called with the indices of the servos whose Bus Watchdog a check found tripped
    (it re-arms them); None: a trip stops the performance at once.
    """

    def __init__(self, bus: DriveBus, opts: PerformOptions, on_trip=None) -> None:
        self.bus, self.opts, self.on_trip = bus, opts, on_trip
        k = len(bus.ids)
        self.stop = CurrentTemperatureStop(
            bus.ids, [bus.setup[i] for i in bus.ids], temperature_margin_c=opts.temperature_margin_c,
            temperature_cap_c=opts.temperature_cap_c, current_fraction=opts.current_fraction,
            current_sustain_s=opts.current_sustain_s)
        self.misses = np.zeros(k, np.int64)
        self.trips = np.zeros(k, np.int64)
        self.rescues = 0
        self.cycles = 0

    def check(self, state, dt: float) -> None:
        bus = self.bus
        self.cycles += 1
        for n in np.flatnonzero(state.alert):
            dxl_id = bus.ids[n]
            try:
                bits = bus.hardware_error(dxl_id)
                what = describe_hardware_error(bits)
            except BusError as err:
                what = f"unreadable ({err})"
            raise HealthStop(dxl_id, f"hardware error: {what} (alert bit in its status)")
        self._check_misses(state)
        self.stop.check(state, dt)
        if self.opts.watchdog and self.cycles % WATCHDOG_CHECK_CYCLES == 0:
            self._check_watchdogs()

    def _check_misses(self, state) -> None:
        """Servos without a usable reading for READ_FAILURES_TO_STOP cycles: read each alone;
        those that fail stop the performance, named (see the module docstring)."""
        if state.ok.all():
            self.rescues = 0
        self.misses = np.where(state.ok, 0, self.misses + 1)
        late = np.flatnonzero(self.misses >= READ_FAILURES_TO_STOP)
        if not late.size:
            return
        ids = [self.bus.ids[n] for n in late]
        cycles = int(self.misses[late].max())
        silent = self.bus.unanswered(ids)
        if silent:
            names = sorted(silent)
            raise DriveError(f"servo{'s' if len(names) > 1 else ''} {', '.join(map(str, names))}: "
                             f"no usable reading for {cycles} cycles, nor alone "
                             f"({silent[names[0]]})")
        self.rescues += 1
        if self.rescues >= RESCUES_TO_STOP:
            raise DriveError(f"servos {ids}: the state read failed {cycles} cycles in a row "
                             f"{self.rescues} times though each answers alone "
                             f"({state.failures.get(ids[0])})")
        self.misses[late] = 0  # each answered alone: the replies were late, not missing

    def _check_watchdogs(self) -> None:
        values = self.bus.read_watchdogs()
        tripped: list[int] = []
        for n, dxl_id in enumerate(self.bus.ids):
            if values.get(dxl_id) != it.WATCHDOG_TRIPPED:
                if dxl_id in values:
                    self.trips[n] = 0
                continue
            self.trips[n] += 1
            if self.on_trip is None or self.trips[n] >= WATCHDOG_TRIPS_TO_STOP:
                again = f", {self.trips[n]} checks in a row" if self.trips[n] > 1 else ""
                raise HealthStop(dxl_id, "Bus Watchdog tripped (it heard nothing for longer "
                                 f"than its period{again}): it stopped and refuses goals")
            tripped.append(n)
        if tripped:
            self.on_trip(tripped)


def _playback(bus: DriveBus, goals: TakeGoals, servo_map, start_pose: np.ndarray, opts, report,
              say, check_signal, phase, notices: _Notices) -> None:
    """The loop: one goal Sync Write and one state Sync Read per cycle, paced to rate_hz."""
    phase("playback")
    period = 1.0 / opts.rate_hz
    lo, hi = _limits(bus, goals)
    max_step = goals.units.ticks_per_joint_degree * (opts.max_speed_deg_s * period)
    shaper = GoalShaper(lo, hi, max_step)
    shaper.start(start_pose)
    ease_step = goals.units.ticks_per_joint_degree * (opts.start_speed_deg_s * period)

    def rearm(n: int) -> None:  # a stall tripped its watchdog: ease back from where it stopped
        shaper.ease(n, bus.rearm(bus.ids[n], _watchdog_units(opts)), ease_step[n])

    health = _Health(bus, opts, on_trip=lambda tripped: _rearm_all(tripped, rearm, bus, report,
                                                                   notices))
    unsent = 0
    errors = Histogram()  # |present - goal|, degrees: bounded, whatever the length (--loop)
    t0 = time.monotonic()
    next_t = t0
    last_write = t0
    stale_s = max(opts.watchdog_ms / 1000.0, 3 * period)
    cycles = 0
    take_len = goals.duration_s
    while True:
        check_signal()
        now = time.monotonic()
        t_take = (now - t0) * opts.speed
        if t_take > take_len:
            if not opts.loop:
                break
            t_take %= take_len if take_len > 0 else 1.0
        if now - last_write > stale_s:
            notices.add(STALLED, detail=f" ({now - last_write:.3f} s since the last goal frame)")
        wanted = goals.at(t_take)
        command = shaper.shape(wanted)
        try:
            bus.write_goals(command)
            unsent = 0
            last_write = time.monotonic()
        except ServoTimeout as err:  # not sent: the line is stalled (replies still pending)
            if not err.line_stalled:
                raise
            unsent += 1
            report.unsent_cycles += 1
            if unsent >= READ_FAILURES_TO_STOP:
                raise DriveError(f"goals not sent for {unsent} cycles in a row: {err}") from err
        state = bus.read_state()
        health.check(state, period)
        target = np.clip(np.where(np.isnan(wanted), command, wanted), lo, hi)
        err = goals.degrees(np.where(state.ok, state.position - target, 0))
        errors.add_each(err[state.ok])
        cycles += 1
        report.cycles = cycles
        next_t += period
        sleep = next_t - time.monotonic()
        if sleep > 0:
            time.sleep(sleep)
        else:
            next_t = time.monotonic()
    elapsed = time.monotonic() - t0
    report.cycles = cycles
    report.playback_s = elapsed
    report.rate_hz = cycles / elapsed if elapsed > 0 else 0.0
    report.clamped = {i: int(c) for i, c in zip(bus.ids, shaper.clamped) if c}
    report.rate_limited = {i: int(c) for i, c in zip(bus.ids, shaper.rate_limited) if c}
    if report.clamped:
        say(f"goals clamped to the limits (cycles per servo): {report.clamped}")
    if errors.count:  # within half a bin (0.025 deg) of the exact percentiles
        report.tracking_median_deg = errors.percentile(50)
        report.tracking_p99_deg = errors.percentile(99)
