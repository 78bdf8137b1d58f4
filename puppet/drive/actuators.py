"""Actuator servos in ``live``: a cycle hook that runs inside the reader process.

A rig's ``role = "actuator"`` servos are driven to the angle the solve gives their joint. The
host computes wanted goal ticks from each frame's solve (``LiveActuation``) and hands them to
the reader process (``ReaderProcess.set_goals``); there ``ActuatorHook``, the process's cycle hook
(puppet.bus.reader_process.CycleHook), writes them with one Sync Write per bus cycle just before
the cycle's sensor read, after the same clamps and per-cycle rate limit as ``perform``
(``GoalShaper``). The reader leaves these servos' torque alone (they are its ``driven`` ids):
this hook alone turns it on and off.

Setup (``start``, torque off throughout until the end): the actuators are made safe to drive by
``DriveBus.prepare`` (position mode, no torque-on-by-goal, return delay 0; EEPROM items only with
torque off, only when they differ, every change logged; a tripped Bus Watchdog is cleared),
then Goal Position := Present Position, torque on, and the Bus Watchdog set. ``stop`` turns
torque off (``DriveBus.torque_off``: group write, servo by servo, read back, watchdog cleared).

Watched while driving: every ``WATCHDOG_CHECK_CYCLES`` cycles the actuators' Bus Watchdog is
read. A trip (-1: the host was silent longer than its period, e.g. a stalled or stopped
process) is a ``watchdog_tripped`` bus event, and the actuator is re-armed: watchdog cleared,
goal := present, and the goals ease back to the solve at ``EASE_BACK_DEG_S`` from there. A
watchdog that reads 0 although it was set means the servo rebooted (torque off, RAM defaults),
and a latched hardware error (the reader's health) means it shut its torque off: either stops
that actuator, torque off, as an ``actuator_stopped`` event; the others go on.

Health: at the same checks the actuators' state is read (one Sync Read of Moving .. Present
Temperature) and checked by ``health.CurrentTemperatureStop``, the same current (or load) and
temperature stop as ``perform``, caps from each servo through the model table: an actuator over
a limit is stopped, torque off, as an ``actuator_stopped`` event naming what was read.

A port that stays down ``PORT_GONE_S`` is noted once with what to do (torque may still be on:
``puppet release``); a port that comes back within the watchdog period goes on, a later one
finds the watchdog tripped and eases back as above.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from puppet.bus.errors import BusError
from puppet.bus.link import BusLink
from puppet.drive import items as it
from puppet.drive.errors import HealthStop
from puppet.drive.goals import GoalShaper
from puppet.drive.health import CurrentTemperatureStop
from puppet.drive.servos import DriveBus
from puppet.servo_models import ServoUnits, describe_hardware_error, protocol_of


@dataclass(frozen=True)
class ActuationPlan:
    """What the reader process needs to drive a rig's actuators (picklable).

    ids: (a,) actuator ids, map order. models: {id: model}. lo / hi: (a,) goal-tick limits
    (continuous ticks, from the joint limits through the calibration). max_step: (a,) most ticks
    a goal moves per bus cycle. watchdog_units: Bus Watchdog, 20 ms units (0: not set).
    max_speed_deg_s: the joint speed max_step stands for.
    """

    ids: tuple[int, ...]
    models: dict
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    max_step: tuple[float, ...]
    watchdog_units: int
    max_speed_deg_s: float = 360.0

    @classmethod
    def for_rig(cls, rig, rate_hz: float, *, max_speed_deg_s: float = 360.0,
                watchdog_ms: float = 100.0) -> "ActuationPlan | None":
        """The plan for ``rig``'s actuators read at ``rate_hz`` (None: the rig has none).
        max_speed_deg_s: joint speed limit of the goals (as ``perform``'s); watchdog_ms: the Bus
        Watchdog period (at least three bus cycles; 0 = not set: --no-watchdog). With a
        watchdog, an actuator whose model has none is refused (RigError naming servo, model and
        line)."""
        servos = rig.servo_map.actuators
        if not servos:
            return None
        if watchdog_ms > 0:
            from puppet.rig.servo_map import check_bus_watchdogs  # the parent's side only

            check_bus_watchdogs(servos, rig.servo_map.path)
        units = ServoUnits.for_servos(servos, rig.servo_map.zero[rig.servo_map.actuator_index])
        lo, hi = units.tick_limits()
        step = units.ticks_per_joint_degree * (max_speed_deg_s / rate_hz)
        watchdog_units = 0
        if watchdog_ms > 0:
            ms = max(watchdog_ms, 3 * 1000.0 / rate_hz)
            watchdog_units = max(1, min(127, math.ceil(ms / (it.WATCHDOG_UNIT_S * 1000.0))))
        return cls(tuple(int(s.id) for s in servos), {int(s.id): s.model for s in servos},
                   tuple(lo.tolist()), tuple(hi.tolist()), tuple(step.tolist()), watchdog_units,
                   float(max_speed_deg_s))


WATCHDOG_CHECK_CYCLES = 25
"""Bus cycles between two reads of the actuators' Bus Watchdog and of their current and
temperature (50 ms at live's 500 Hz: well inside the 0.3 s a current must last to stop)."""
EASE_BACK_DEG_S = 45.0
"""Joint speed (degrees/s) at which a re-armed actuator's goal goes from its present position
back to the solve."""
PORT_GONE_S = 2.0
"""A port down this long is reported (once) as one that may have left torque on."""


class ActuatorHook:
    """Drives ``plan``'s actuators on the reader's link, in the reader process (a CycleHook).

    Picklable until ``start``. ``ids`` (a,) the actuators; ``shaper`` the clamps and rate limit
    in use; ``active`` (a,) bool: not stopped (torque on and driven).
    """

    def __init__(self, plan: ActuationPlan) -> None:
        self.plan = plan
        self.ids = plan.ids
        self.bus: DriveBus | None = None
        self.reader = None
        self.shaper: GoalShaper | None = None
        self.torque_on = False
        self.active = np.zeros(len(plan.ids), bool)
        self.offsets = np.zeros(len(plan.ids))
        self.cycles = 0
        self.health: CurrentTemperatureStop | None = None
        self._checked_ns = 0
        self._port_down_ns = 0
        self._port_noted = False

    # ---- CycleHook ---------------------------------------------------------------------------
    def start(self, reader, note) -> list:
        """Setup with torque off, goal := present, torque on, Bus Watchdog set -> the setup's
        Changes. DriveError or BusError on a refusal (torque is then still off)."""
        plan = self.plan
        self.reader = reader
        self.bus = bus = DriveBus(reader.link, plan.ids, plan.models, note)
        bus.prepare(use_watchdog=plan.watchdog_units > 0)
        lo, hi = np.array(plan.lo), np.array(plan.hi)
        present = np.zeros(len(plan.ids))
        for n, dxl_id in enumerate(plan.ids):
            raw = bus.read(dxl_id, "present_position")
            bus.write(dxl_id, "goal_position", raw)
            self.offsets[n] = reader.unwrap[dxl_id].offset
            present[n] = raw + self.offsets[n]
            info = bus.setup[dxl_id]
            if info.lo is not None:  # the servo's own limits (position mode), continuous
                lo[n] = max(lo[n], info.lo + self.offsets[n])
                hi[n] = min(hi[n], info.hi + self.offsets[n])
        self.shaper = GoalShaper(lo, hi, np.array(plan.max_step))
        self.shaper.start(present)
        self.health = CurrentTemperatureStop(plan.ids, [bus.setup[i] for i in plan.ids])
        self._checked_ns = time.monotonic_ns()
        self._slow = np.array(plan.max_step) * min(1.0, EASE_BACK_DEG_S / plan.max_speed_deg_s)
        self._raw = dict.fromkeys(plan.ids, 0)
        self.torque_on = True  # from here on, stop() turns it off
        self.active[:] = True
        bus.write_all("torque_enable", 1)
        if plan.watchdog_units:
            bus.write_all("bus_watchdog", plan.watchdog_units)
        return list(bus.changes)

    def before_read(self, reader, goals: np.ndarray) -> None:
        """One Sync Write of Goal Position toward ``goals`` ((a,) continuous ticks; NaN:
        hold), clamped and rate-limited; the watchdog check every WATCHDOG_CHECK_CYCLES."""
        if not self.active.any():
            return
        if not reader.port_up:
            self._port_gone(reader)
            return
        self._port_down_ns = 0
        self.cycles += 1
        try:
            self.write(goals)
            if self.cycles % WATCHDOG_CHECK_CYCLES == 0:
                self._watch(reader)
        except BusError as exc:  # the reader's own read finds a lost port and recovers it
            reader.log.add("write_failed", list(self.ids), str(exc))

    def stop(self) -> dict[int, int | None] | None:
        """Torque off (group write, then one by one, read back; watchdog cleared) -> {id:
        Torque Enable read back, None when unreadable}; None when torque never went on."""
        if not self.torque_on:
            return None
        self.torque_on = False
        self.active[:] = False
        return self.bus.torque_off()

    def stop_from_parent(self, port: str, options: dict, note) -> dict[int, int | None] | None:
        """The reader process died with the actuators' torque maybe on: open ``port`` here and
        turn it off (read back); None when the port cannot be opened (noted)."""
        link = BusLink(port, **{k: v for k, v in options.items() if k in ("baud", "latency_ms")},
                       protocol=protocol_of(self.plan.models))
        try:
            link.open()
            return DriveBus(link, self.plan.ids, self.plan.models, note).torque_off()
        except BusError as err:
            note(f"torque off after the reader process died failed: {err}")
            return None
        finally:
            link.close()

    # ---- the cycle ---------------------------------------------------------------------------
    def write(self, wanted: np.ndarray) -> np.ndarray:
        """One Sync Write of the active actuators' goals toward ``wanted`` (a,); -> the (a,)
        goals (reused array)."""
        goals = self.shaper.shape(wanted)
        raw = self._raw
        for n, dxl_id in enumerate(self.plan.ids):
            if self.active[n]:
                raw[dxl_id] = int(round(goals[n] - self.offsets[n]))
        self.bus.write_goal_table(raw)
        return goals

    def _watch(self, reader) -> None:
        """The watchdog check: hardware errors (the servo's own stop, named first), a current
        (or load) or temperature over the host's limits and reboots stopped; trips re-armed."""
        for n, dxl_id in enumerate(self.plan.ids):
            if self.active[n] and reader.health[dxl_id].hardware_error:
                self._stop_one(n, reader, "hardware error latched: "
                               f"{describe_hardware_error(reader.health[dxl_id].hardware_error)}")
        if self.active.any():
            self._check_health(reader)
        if not self.plan.watchdog_units:
            return
        for dxl_id, value in self.bus.read_watchdogs().items():
            n = self.plan.ids.index(dxl_id)
            if not self.active[n]:
                continue
            if value == it.WATCHDOG_TRIPPED:
                self._rearm(n, reader)
            elif value == 0:
                self._stop_one(n, reader, "its Bus Watchdog reads 0 although set: it rebooted "
                               "(torque off)")

    def _check_health(self, reader) -> None:
        """Read the actuators' state; stop each one over a current or temperature limit."""
        state = self.bus.read_state()
        now = time.monotonic_ns()
        dt, self._checked_ns = (now - self._checked_ns) * 1e-9, now
        for n in np.flatnonzero(state.alert & self.active):  # its own stop: named as such
            try:
                what = describe_hardware_error(self.bus.hardware_error(self.plan.ids[n]))
            except BusError as err:
                what = f"unreadable ({err})"
            self._stop_one(int(n), reader, f"hardware error latched: {what}")
        state.ok &= self.active  # a stopped actuator is no longer watched
        while True:
            try:
                self.health.check(state, dt)
                return
            except HealthStop as stop:
                n = self.plan.ids.index(stop.dxl_id)
                self._stop_one(n, reader, stop.reading)
                state.ok[n] = False
                dt = 0.0  # the others' time over the cap was counted already

    def _rearm(self, n: int, reader) -> None:
        """Watchdog tripped: clear it, goal := present, ease back from there, watchdog set."""
        dxl_id, bus = self.plan.ids[n], self.bus
        reader.log.add("watchdog_tripped", [dxl_id],
                       "Bus Watchdog tripped (the host was silent longer than "
                       f"{self.plan.watchdog_units * it.WATCHDOG_UNIT_S * 1000:.0f} ms): re-armed, "
                       f"easing back to the solve at {EASE_BACK_DEG_S:.0f} deg/s")
        raw = bus.rearm(dxl_id, self.plan.watchdog_units)
        self.shaper.ease(n, raw + self.offsets[n], self._slow[n])

    def _stop_one(self, n: int, reader, why: str) -> None:
        dxl_id = self.plan.ids[n]
        self.active[n] = False
        del self._raw[dxl_id]
        try:
            self.bus.write(dxl_id, "torque_enable", 0)
            after = self.bus.read(dxl_id, "torque_enable")
        except BusError as err:
            after = f"unknown ({err})"
        reader.log.add("actuator_stopped", [dxl_id], f"{why}; stopped, Torque Enable reads {after}")

    def _port_gone(self, reader) -> None:
        now = time.monotonic_ns()
        if not self._port_down_ns:
            self._port_down_ns = now
        elif not self._port_noted and now - self._port_down_ns > PORT_GONE_S * 1e9:
            self._port_noted = True
            port = reader.link.port_name
            reader.log.add("port_gone", list(self.ids),
                           f"{port} gone for {PORT_GONE_S:.0f} s: actuators {list(self.ids)} may "
                           "still have torque on (their Bus Watchdog stops them); when the "
                           f"adapter is back, `puppet release --port {port}` turns it off")


class LiveActuation:
    """The host's side in ``live``: each frame's solve -> the actuators' wanted goals, handed
    to the reader process's goal channel (``source.set_goals``).

    rig: the rig (its ``servo_map.actuators``); ``source``: set it to the started ReaderProcess
    whose hook is this rig's ``ActuatorHook``. Use ``after_solve`` as ``run_live``'s hook.
    """

    def __init__(self, rig, source=None) -> None:
        from puppet.drive.actuate import ActuatorGoals

        sm = rig.servo_map
        self.source = source
        self.goals = ActuatorGoals(sm.actuators, rig.skeleton, sm.zero[sm.actuator_index])

    def after_solve(self, pipeline, reading) -> None:
        self.source.set_goals(self.goals.goals(pipeline.T), reading.t_ns)
