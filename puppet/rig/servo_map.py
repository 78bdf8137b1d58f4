"""Servo map: which servo senses which joint axis, and ticks -> joint angles.

The conversion is ``puppet.servo_models.ServoUnits`` (``angle = sign · (ticks − zero) · 2π /
ticks_per_turn / gear``, its one wrap rule, clamped to the servo's limits), so a servo that
rebooted (its multi-turn count reset) still reads the right angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from puppet.rig.calibration import INT32, Calibration
from puppet.rig.errors import RigError
from puppet.rig.skeleton import Joint, Skeleton

from puppet.servo_models import MODELS, ServoUnits, known_models, protocol_of

GEAR_RANGE = (0.01, 100.0)
"""Servo turns per joint turn: a gear ratio outside this is a typo, not a mechanism."""
LIMIT_RANGE = (-2 * np.pi, 2 * np.pi)
"""Joint limits (radians) lie within one turn either side of the rest pose."""
ROLES = ("sensor", "actuator")
"""A sensor reads its joint (the puppeteer moves it); an actuator drives a joint the solve fills
in (free or relative) to the solved angle, in ``live``."""


@dataclass(frozen=True)
class Servo:
    """One servo used as a joint-angle sensor.

    id:         bus id (0..252).
    model:      model name, e.g. "XL330-M288".
    joint:      name of the bone whose joint it senses.
    axis:       (3,) unit axis in that bone's rest frame.
    order:      composition order within the joint (1 = outermost).
    sign:       +1 or -1.
    gear:       joint turns per servo turn is 1/gear (> 0).
    zero_ticks: ticks at the rest pose (a Calibration overrides it).
    limits:     (lo, hi) joint angle limits, radians, lo < hi.
    line:       line of the servo's table in the map file (0 when built in code).
    role:       "sensor" (reads its joint) or "actuator" (driven to the solved angle of a
                joint the solve fills in; it does not make its joint sensed).
    """

    id: int
    model: str
    joint: str
    axis: np.ndarray
    order: int = 1
    sign: int = 1
    gear: float = 1.0
    zero_ticks: int = 2048
    limits: tuple[float, float] = (-np.pi, np.pi)
    line: int = 0
    role: str = "sensor"


class ServoMap:
    """Ordered servos of a rig; index i of every per-servo array is ``servos[i]``.

    ids:    (k,) int64 servo ids, in map order (the bus reads in this order).
    models: {id: model name}.
    zero:   (k,) int64 zero ticks in use (map values, overridden by a calibration).
    """

    def __init__(self, servos, calibration: Calibration | None = None, path=None) -> None:
        self.servos = tuple(servos)
        self.path = path
        seen: dict[int, Servo] = {}
        for s in self.servos:
            _check_servo(s, path)
            if s.id in seen:
                raise RigError(f"duplicate servo id {s.id} (first at line {seen[s.id].line})",
                               path=path, line=s.line or None, field=f"servo {s.id} id")
            seen[s.id] = s
        self.ids = np.array([s.id for s in self.servos], np.int64)
        self.models = {s.id: s.model for s in self.servos}
        _check_one_protocol(self.servos, path)
        self.actuator_index = np.array([i for i, s in enumerate(self.servos)
                                        if s.role == "actuator"], np.int64)
        """(a,) indices of the actuator servos, map order (empty: a pure sensor rig)."""
        self.units = ServoUnits.for_servos(self.servos)
        """Ticks <-> joint radians of every servo (its ``zero`` is ``self.zero``)."""
        self.zero = self.units.zero
        self.calibration = Calibration()
        if calibration is not None:
            self.calibrate(calibration)
        else:
            check_model_ranges(self.servos, self.zero, path)

    def __len__(self) -> int:
        return len(self.servos)

    def calibrate(self, calibration: Calibration) -> None:
        """Use ``calibration``'s zero ticks (servos it does not name keep the map's zero)."""
        zero = [calibration.zero_for(s.id, s.zero_ticks) for s in self.servos]
        check_model_ranges(self.servos, zero, self.path, calibration.path)
        self.calibration = calibration
        self.zero[:] = zero

    def angles(self, ticks: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Joint angles from raw ticks.

        ticks: (k,) int32 encoder counts in map order. out: optional (k,) float64.
        Returns (k,) float64 radians, clamped to each servo's limits.
        """
        return self.units.angles(ticks, out)

    def ticks_for(self, angles: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`angles` (no clamping): (k,) radians -> (k,) int32 ticks."""
        return np.rint(self.units.ticks(angles)).astype(np.int32)

    @property
    def actuators(self) -> tuple[Servo, ...]:
        """The servos with ``role = "actuator"``, map order."""
        return tuple(self.servos[i] for i in self.actuator_index)

    def joints(self, skeleton: Skeleton) -> tuple[Joint, ...]:
        """Group sensor servos by joint into skeleton joints; dof i is servo i (actuators
        sense nothing: their joints are left to the solve).

        Raises RigError naming the line for an unknown joint, more than three servos on one
        joint, or two servos with the same order on one joint.
        """
        by_bone: dict[int, list[int]] = {}
        for i, s in enumerate(self.servos):
            if s.joint not in skeleton.names:
                raise RigError(f"unknown joint {s.joint!r}; bones are {list(skeleton.names)}",
                               path=self.path, line=s.line or None, field=f"servo {s.id} joint")
            if s.role != "actuator":
                by_bone.setdefault(skeleton.index(s.joint), []).append(i)
        joints = []
        for bone, members in sorted(by_bone.items()):
            name = skeleton.names[bone]
            if len(members) > 3:
                ids = [self.servos[i].id for i in members]
                raise RigError(f"joint {name!r} has {len(members)} servos {ids}; at most 3",
                               path=self.path, line=self.servos[members[3]].line or None,
                               field=f"servo {self.servos[members[3]].id} joint")
            orders = [self.servos[i].order for i in members]
            if len(set(orders)) != len(orders):
                dup = next(i for i in members if orders.count(self.servos[i].order) > 1
                           and i != members[orders.index(self.servos[i].order)])
                raise RigError(f"joint {name!r}: two servos with order {self.servos[dup].order}",
                               path=self.path, line=self.servos[dup].line or None,
                               field=f"servo {self.servos[dup].id} order")
            for a, first in enumerate(members):
                for second in members[a + 1:]:
                    one, two = self.servos[first], self.servos[second]
                    if abs(float(np.dot(one.axis, two.axis))) > 1.0 - 1e-6:
                        raise RigError(f"joint {name!r}: servos {one.id} and {two.id} both turn "
                                       f"about one axis {np.round(one.axis, 6).tolist()}; the "
                                       "solve cannot tell their angles apart (give each servo "
                                       "of a joint its own axis)", path=self.path,
                                       line=two.line or None, field=f"servo {two.id} axis")
            members.sort(key=lambda i: self.servos[i].order)
            joints.append(Joint(bone, np.array([self.servos[i].axis for i in members], float),
                                np.array(members, np.int64)))
        return tuple(joints)


def check_bus_watchdogs(servos, path=None, models=MODELS) -> None:
    """Refuse to drive a servo whose model has no Bus Watchdog (``bus_watchdog_firmware`` None
    in the model table): RigError naming the servo, its model and its line. ``perform`` checks
    every servo it drives, ``live`` its actuators, unless given --no-watchdog."""
    for s in servos:
        if models[s.model].bus_watchdog_firmware is None:
            raise RigError(f"model {s.model} has no Bus Watchdog: if this host stopped, the servo "
                           "would hold its last goal with torque on; drive a model that has one, "
                           "or pass --no-watchdog", path=path, line=s.line or None,
                           field=f"servo {s.id} model")


def _check_one_protocol(servos, path) -> None:
    """RigError naming the servos of each protocol (and the line of the first that differs
    from the first servo's) when the rig mixes Protocol 1.0 and 2.0 models: one bus carries
    one protocol (``puppet.servo_models.protocol_of``)."""
    try:
        protocol_of({s.id: s.model for s in servos})
    except ValueError as err:
        first = MODELS[servos[0].model].protocol
        odd = next(s for s in servos if MODELS[s.model].protocol != first)
        raise RigError(str(err), path=path, line=odd.line or None,
                       field=f"servo {odd.id} model") from None


def check_model_ranges(servos, zero, path=None, calibration_path=None) -> None:
    """Refuse joint limits a servo's model cannot measure: RigError naming the servo, its
    model and its line. On a model whose positions cover less than a turn (AX / RX / XL-320:
    1024 positions over 300°, a 60° dead zone) the limits, turned into servo ticks through the
    servo's gear, sign and ``zero`` (ticks in use, (k,)), must lie within its positions
    0..max_position (a zero from a calibration file names that file too). A model whose
    positions cover the whole turn takes any limits (X-series count turns; MX on Protocol 1.0
    is unwrapped by the bus)."""
    for s, z in zip(servos, zero):
        model = MODELS[s.model]
        if not model.dead_zone_deg:
            continue
        units = ServoUnits([s.sign], [s.gear], [int(z)], [s.limits], model.ticks_per_turn)
        lo, hi = (float(t[0]) for t in units.tick_limits())
        if 0 <= lo and hi <= model.max_position:
            continue
        span = float(np.degrees(s.limits[1] - s.limits[0])) * s.gear
        why = (f"span {span:.0f}° of the servo's shaft, more than the {model.position_range_deg:.0f}° "
               "it measures" if span > model.position_range_deg else
               f"from zero_ticks {int(z)}{' (' + str(calibration_path) + ')' if calibration_path else ''}"
               f" they reach ticks {lo:.0f}..{hi:.0f}")
        raise RigError(
            f"limits {np.degrees(s.limits[0]):.0f}..{np.degrees(s.limits[1]):.0f}° outside what its "
            f"{s.model} measures ({why}; its positions are 0..{model.max_position}, the other "
            f"{model.dead_zone_deg:.0f}° of the turn are its dead zone): narrow limits_deg, or "
            "re-mount the horn so the joint's range sits inside the servo's",
            path=path, line=s.line or None, field=f"servo {s.id} limits_deg")


def _check_servo(s: Servo, path) -> None:
    """RigError naming the servo (and its line) unless every field is in range and finite."""
    def fail(message, key):
        raise RigError(message, path=path, line=s.line or None, field=f"servo {s.id} {key}")

    if isinstance(s.id, bool) or not isinstance(s.id, (int, np.integer)) or not 0 <= s.id <= 252:
        fail(f"id must be an integer 0..252, got {s.id!r}", "id")
    if not isinstance(s.model, str) or s.model not in MODELS:
        fail(f"unknown model {s.model!r} (known: {known_models()})", "model")
    axis = np.asarray(s.axis, dtype=float)
    if axis.shape != (3,) or not np.isfinite(axis).all() or not abs(np.linalg.norm(axis) - 1) < 1e-6:
        fail(f"axis must be a finite (3,) unit vector, got {axis.tolist()}", "axis")
    if s.role not in ROLES:
        fail(f"role must be one of {', '.join(ROLES)}, got {s.role!r}", "role")
    if s.sign not in (1, -1):
        fail(f"sign must be 1 or -1, got {s.sign!r}", "sign")
    if not GEAR_RANGE[0] <= s.gear <= GEAR_RANGE[1]:  # also false for nan
        fail(f"gear must be {GEAR_RANGE[0]}..{GEAR_RANGE[1]}, got {s.gear!r}", "gear")
    if not INT32[0] <= s.zero_ticks <= INT32[1]:
        fail(f"zero ticks must be a 32-bit integer, got {s.zero_ticks!r}", "zero_ticks")
    lo, hi = s.limits
    if not LIMIT_RANGE[0] <= lo < hi <= LIMIT_RANGE[1]:
        fail(f"limits must be finite radians with low < high within one turn, got {s.limits!r}",
             "limits")
