"""Actuator servos in ``live``: the bus side, run inside the reader process.

A rig's ``role = "actuator"`` servos are driven to the angle the solve gives their joint. The
host computes wanted goal ticks from each frame's solve (``ActuatorGoals``) and hands them to
the reader process; there ``ActuatorDriver`` writes them with one Sync Write per bus cycle, just
before the cycle's sensor read, after the same clamps and per-cycle rate limit as ``perform``
(``GoalShaper``).

Setup (``start``, torque off throughout until the end): the actuators are made safe to drive by
``DriveBus.prepare`` (position mode, no torque-on-by-goal, return delay 0; EEPROM items only with
torque off, only when they differ, every change logged; a tripped Bus Watchdog is cleared),
then Goal Position := Present Position, torque on, and the Bus Watchdog set. ``stop`` turns
torque off (``DriveBus.torque_off``: group write, servo by servo, read back, watchdog cleared).

Health: every ``HEALTH_CHECK_CYCLES`` goal writes the actuators' state is read (one Sync Read of
Moving .. Present Temperature) and checked by ``health.CurrentTemperatureStop``, the same current
(or load) and temperature stop as ``perform``, caps from each servo through the model table. A
stop turns the actuators' torque off (read back), logs the reason and ends their driving
(``stopped``); the sensors read on.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from puppet.drive import items as it
from puppet.drive.errors import HealthStop
from puppet.drive.goals import GoalShaper
from puppet.drive.health import CurrentTemperatureStop
from puppet.drive.servos import DriveBus
from puppet.servo_models import ServoUnits


HEALTH_CHECK_CYCLES = 10
"""The actuators' current and temperature are read every this many goal writes (a few tens of ms
at the reader's rates, well inside the 0.3 s a current must be sustained to stop)."""


@dataclass(frozen=True)
class ActuationPlan:
    """What the reader process needs to drive a rig's actuators (picklable).

    ids: (a,) actuator ids, map order. models: {id: model}. lo / hi: (a,) goal-tick limits
    (continuous ticks, from the joint limits through the calibration). max_step: (a,) most ticks
    a goal moves per bus cycle. watchdog_units: Bus Watchdog, 20 ms units (0: not set).
    """

    ids: tuple[int, ...]
    models: dict
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    max_step: tuple[float, ...]
    watchdog_units: int

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
                   tuple(lo.tolist()), tuple(hi.tolist()), tuple(step.tolist()), watchdog_units)


class ActuatorDriver:
    """Drives ``plan``'s actuators on an open ServoReader's link (in the reader process).

    log: called with one line of text per change, recovery or failure.
    ``present`` (a,) continuous ticks at start; ``shaper`` the clamps and rate limit in use;
    ``stopped``: why the health check stopped the actuators (None while driving);
    ``torque_after``: what the stop read back ({id: Torque Enable or None}).
    """

    def __init__(self, plan: ActuationPlan, reader, log) -> None:
        self.plan = plan
        self.reader = reader
        self.bus = DriveBus(reader.link, plan.ids, plan.models, log)
        self.offsets = np.zeros(len(plan.ids))
        self.shaper: GoalShaper | None = None
        self.torque_on = False
        self._raw: dict[int, int] = dict.fromkeys(plan.ids, 0)
        self._hold = np.full(len(plan.ids), np.nan)
        self.health: CurrentTemperatureStop | None = None
        self.stopped: str | None = None
        self.torque_after: dict[int, int | None] = {}
        self._writes = 0
        self._checked_t = 0.0

    def start(self) -> None:
        """Setup with torque off, goal := present, torque on, Bus Watchdog set (DriveError or
        BusError on a refusal; torque is then still off)."""
        bus, plan = self.bus, self.plan
        bus.prepare(use_watchdog=plan.watchdog_units > 0)
        lo, hi = np.array(plan.lo), np.array(plan.hi)
        present = np.zeros(len(plan.ids))
        for n, dxl_id in enumerate(plan.ids):
            raw = bus.read(dxl_id, it.PRESENT_POSITION)
            bus.write(dxl_id, it.GOAL_POSITION, raw)
            self.offsets[n] = self.reader.unwrap[dxl_id].offset
            present[n] = raw + self.offsets[n]
            info = bus.setup[dxl_id]
            if info.lo is not None:  # the servo's own limits (position mode), continuous
                lo[n] = max(lo[n], info.lo + self.offsets[n])
                hi[n] = min(hi[n], info.hi + self.offsets[n])
        self.shaper = GoalShaper(lo, hi, np.array(plan.max_step))
        self.shaper.start(present)
        self.health = CurrentTemperatureStop(plan.ids, [bus.setup[i] for i in plan.ids])
        self._checked_t = time.monotonic()
        self.torque_on = True  # from here on, stop() turns it off
        bus.write_all(it.TORQUE_ENABLE, 1)
        if plan.watchdog_units:
            bus.write_all(it.BUS_WATCHDOG, plan.watchdog_units)

    def write(self, wanted: np.ndarray | None) -> np.ndarray:
        """One Sync Write of Goal Position toward ``wanted`` ((a,) continuous ticks; None or
        NaN: hold), clamped and rate-limited; returns the (a,) goals written (reused array).
        Every HEALTH_CHECK_CYCLES calls the health check first; once it stopped the actuators
        nothing is written."""
        if self.stopped is not None:
            return self.shaper.last
        self._writes += 1
        if self._writes % HEALTH_CHECK_CYCLES == 0 and self._healthy() is False:
            return self.shaper.last
        goals = self.shaper.shape(self._hold if wanted is None else wanted)
        raw = self._raw
        for n, dxl_id in enumerate(self.plan.ids):
            raw[dxl_id] = int(round(goals[n] - self.offsets[n]))
        self.reader.link.sync_write(it.GOAL_POSITION, raw)
        return goals

    def _healthy(self) -> bool:
        """Read the actuators' state and check it; on a stop: torque off, logged, False."""
        state = self.bus.read_state()
        now = time.monotonic()
        dt, self._checked_t = now - self._checked_t, now
        try:
            self.health.check(state, dt)
        except HealthStop as stop:
            self.stopped = str(stop)
            # torque_on stays set: the stop at the end reads torque back again for the host
            self.torque_after = self.bus.torque_off()
            self.bus.log(f"{stop} (Torque Enable read back: {self.torque_after})")
            return False
        return True

    def stop(self) -> dict[int, int | None]:
        """Torque off (group write, then one by one, read back; watchdog cleared) -> {id:
        Torque Enable read back, None when unreadable}."""
        self.torque_on = False
        return self.bus.torque_off()


class LiveActuation:
    """The host's side in ``live``: each frame's solve -> the actuators' wanted goals, handed
    to the reader process's goal channel (``source.set_actuator_goals``).

    rig: the rig (its ``servo_map.actuators``); ``source``: set it to the started ReaderProcess
    that has the plan. Use ``after_solve`` as ``run_live``'s hook.
    """

    def __init__(self, rig, source=None) -> None:
        from puppet.drive.actuate import ActuatorGoals

        sm = rig.servo_map
        self.source = source
        self.goals = ActuatorGoals(sm.actuators, rig.skeleton, sm.zero[sm.actuator_index])

    def after_solve(self, pipeline, reading) -> None:
        self.source.set_actuator_goals(self.goals.goals(pipeline.T), reading.t_ns)
