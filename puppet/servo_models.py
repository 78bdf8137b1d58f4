"""Servo units, in one place: the Dynamixel models puppet knows with their per-model facts, and
the paired conversions between encoder ticks and joint radians.

What a rig may name, what the bus can read and check, what ``perform`` and ``live`` may drive
and how they read current, and (through hw_sim's own device-side copy, kept equal field by field
by ``tests/hw_sim/test_hwsim_models.py``) what the simulator serves all come from
:data:`MODELS`. Every model here is a Protocol 2.0 X-series servo with Present Position at
address 132 (4 bytes, signed). This module imports nothing but numpy: the rig, the bus, the
take, drive and hw_sim's agreement test all read it.

Conversions (:class:`ServoUnits`), for a servo of sign ``s``, gear ``g`` (servo turns per joint
turn), zero ``z`` ticks and ``N`` ticks per turn:

    angle = s · (ticks − z) · 2π / N / g        (ticks -> radians, then the wrap, then the clamp)
    ticks = z + angle · N · g / (2π · s)         (radians -> ticks: no wrap, no clamp)

The wrap rule (one, for every servo): when a servo's joint limits span at most one joint turn,
its angle is taken into the one joint turn centred on the middle of its limits,
``(mid − π, mid + π]``; a joint whose limits span more keeps the servo's continuous count. So a
servo that rebooted (its multi-turn count restarted in 0..N−1), or one read a whole turn away,
still reads the angle its joint is at, for any gear; a joint pose is periodic in one turn.
Radians -> ticks is the plain inverse: a goal is an absolute position in the calibration's turn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TICKS_PER_TURN = 4096
"""Encoder counts per output revolution (12-bit absolute encoder): every model below has this
``ticks_per_turn`` (the bus's unwrap and the take's resampling rely on it)."""
HALF_TURN = TICKS_PER_TURN // 2
"""Half a turn of ticks: the largest step a reading may take between two reads and still be
taken the short way round."""

NO_FAST_SYNC_READ = 256
"""Above any Firmware Version (one byte): no firmware of the model has Fast Sync Read."""

PRESENT_LOAD_UNIT_PCT = 0.1
"""Present Load (126) unit, % of the maximum torque, of the models that sense no current
(``current_unit_ma`` None)."""

VELOCITY_UNIT_RPM = 0.229
"""Profile Velocity / Present Velocity unit, rev/min, of every X-series model below."""


@dataclass(frozen=True)
class ServoModel:
    """A Dynamixel model as the host sees it.

    name:                    e.g. "XL430-W250" (what a rig file writes).
    number:                  Model Number (address 0) the servo reports in a ping.
    fast_sync_read_firmware: first firmware version with Fast Sync Read; NO_FAST_SYNC_READ when
                             the model has none (the dual-axis 2XL430).
    current_unit_ma:         mA per unit of Present Current (126) and Current Limit (38); None
                             when the model senses no current (it reports Present Load, 0.1 % of
                             its maximum torque, at 126 and has no Current Limit).
    current_limit:           Current Limit (38) default, in current_unit_ma units (None: none).
    temperature_limit_c:     Temperature Limit (31) default, deg C.
    bus_watchdog_firmware:   first firmware version with the Bus Watchdog (98); None when the
                             model has none (such a model may not be driven unless told).
    ticks_per_turn:          position resolution, encoder ticks per output turn.
    velocity_unit_rpm:       rev/min per unit of Profile Velocity (112) / Present Velocity (128).
    """

    name: str
    number: int
    fast_sync_read_firmware: int
    current_unit_ma: float | None
    current_limit: int | None
    temperature_limit_c: int
    bus_watchdog_firmware: int | None = 38
    ticks_per_turn: int = TICKS_PER_TURN
    velocity_unit_rpm: float = VELOCITY_UNIT_RPM

    @property
    def current_limit_ma(self) -> float | None:
        """The default Current Limit in mA (None: the model senses no current)."""
        if self.current_unit_ma is None or self.current_limit is None:
            return None
        return self.current_limit * self.current_unit_ma

    @property
    def velocity_unit_deg_s(self) -> float:
        """Degrees per second of the servo shaft per velocity unit."""
        return self.velocity_unit_rpm * 360.0 / 60.0


_X330 = dict(fast_sync_read_firmware=46, current_unit_ma=1.0, temperature_limit_c=70)
_X430_LOAD = dict(current_unit_ma=None, current_limit=None)
_XM = dict(fast_sync_read_firmware=45, current_unit_ma=2.69, temperature_limit_c=80)

MODELS: dict[str, ServoModel] = {
    m.name: m
    for m in (
        ServoModel("XL330-M077", 1190, current_limit=1750, **_X330),
        ServoModel("XL330-M288", 1200, current_limit=1750, **_X330),
        ServoModel("XC330-T181", 1210, current_limit=910, **_X330),
        ServoModel("XC330-T288", 1220, current_limit=910, **_X330),
        ServoModel("XC330-M181", 1230, current_limit=2352, **_X330),
        ServoModel("XC330-M288", 1240, current_limit=2352, **_X330),
        ServoModel("XL430-W250", 1060, 45, temperature_limit_c=72, **_X430_LOAD),
        ServoModel("2XL430-W250", 1090, NO_FAST_SYNC_READ, temperature_limit_c=72, **_X430_LOAD),
        ServoModel("XC430-W150", 1070, 45, temperature_limit_c=80, **_X430_LOAD),
        ServoModel("XC430-W240", 1080, 45, temperature_limit_c=80, **_X430_LOAD),
        ServoModel("XM430-W210", 1030, current_limit=1193, **_XM),
        ServoModel("XM430-W350", 1020, current_limit=1193, **_XM),
        ServoModel("XH430-W210", 1010, current_limit=648, **_XM),
        ServoModel("XH430-W350", 1000, current_limit=648, **_XM),
        ServoModel("XM540-W150", 1130, current_limit=2047, **_XM),
        ServoModel("XM540-W270", 1120, current_limit=2047, **_XM),
    )
}
"""Every model a rig may name. Sources: the ROBOTIS e-manual control tables
(emanual.robotis.com/docs/en/dxl/x/<model>/, e.g. xm430-w210, xh430-w350, xm540-w150,
xc330-t181, xc430-w150, xl330-m288, xl430-w250) and the SDK's model list for the numbers:
X330: Present Current and Current Limit in 1.0 mA (XL330 1750, XC330-T 910, XC330-M 2352),
Temperature Limit 70 C; XM430 / XH430-W / XM540: 2.69 mA (XM430 1193, XH430-W 648, XM540 2047;
the 1.34 mA unit belongs to the 24 V XH430-V models, not listed), 80 C; XL430 / 2XL430 / XC430:
Present Load in 0.1 % and no Current Limit, 72 C (XL430) and 80 C (XC430). All: 4096 ticks per
turn, 0.229 rev/min velocity unit, Bus Watchdog (98) from firmware 38 (e-manual "Bus
Watchdog": firmware v38 and above; X330 firmware starts above it)."""
MODELS_BY_NUMBER: dict[int, ServoModel] = {m.number: m for m in MODELS.values()}


def known_models() -> str:
    """The model names, comma separated, for error messages."""
    return ", ".join(MODELS)


def model_named(name: str) -> ServoModel:
    """The model called ``name``; ValueError naming the known models otherwise."""
    try:
        return MODELS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown servo model {name!r}; known: {known_models()}") from None


def radians_per_tick(sign, gear, ticks_per_turn=TICKS_PER_TURN):
    """Joint radians per servo tick, signed: ``sign · 2π / ticks_per_turn / gear`` (scalars or
    arrays alike)."""
    return np.asarray(sign, float) * (2.0 * np.pi) / np.asarray(ticks_per_turn, float) \
        / np.asarray(gear, float)


def ticks_per_degree(ticks_per_turn=TICKS_PER_TURN):
    """Servo ticks per degree of the servo's own shaft (scalar or array)."""
    return np.asarray(ticks_per_turn, float) / 360.0


class ServoUnits:
    """Paired conversions ticks <-> joint radians for k servos (see the module docstring).

    sign: (k,) ±1. gear: (k,) servo turns per joint turn (> 0). zero: (k,) int64 ticks at the
    rest pose, held by reference (a calibration writes into it). limits: (k, 2) joint radians
    (lo, hi), or None for no clamp and no wrap. ticks_per_turn: (k,) or scalar.

    ``radians_per_tick`` (k,) signed; ``ticks_per_joint_degree`` (k,) unsigned.
    """

    def __init__(self, sign, gear, zero, limits=None, ticks_per_turn=TICKS_PER_TURN) -> None:
        k = len(np.atleast_1d(sign))
        self.zero = zero if isinstance(zero, np.ndarray) and zero.dtype == np.int64 \
            else np.asarray(zero, np.int64).reshape(k)
        self.ticks_per_turn = np.broadcast_to(np.asarray(ticks_per_turn, float), (k,)).copy()
        self.radians_per_tick = radians_per_tick(sign, gear, self.ticks_per_turn).reshape(k)
        self.ticks_per_joint_degree = np.pi / 180.0 / np.abs(self.radians_per_tick)
        if limits is None:
            self.lo = np.full(k, -np.inf)
            self.hi = np.full(k, np.inf)
        else:
            limits = np.asarray(limits, float).reshape(k, 2)
            self.lo, self.hi = limits[:, 0].copy(), limits[:, 1].copy()
        span = self.hi - self.lo
        self._wrap = span <= 2.0 * np.pi
        self._any_wrap = bool(self._wrap.any())
        self._top = np.where(self._wrap, (self.lo + self.hi) / 2.0 + np.pi, 0.0)
        self._work = np.empty(k)

    @classmethod
    def for_servos(cls, servos, zero=None) -> "ServoUnits":
        """Units of rig servos (``sign``, ``gear``, ``limits``, ``model``, ``zero_ticks``
        fields); zero: (k,) ticks in use (default each servo's ``zero_ticks``)."""
        servos = tuple(servos)
        if zero is None:
            zero = np.array([s.zero_ticks for s in servos], np.int64)
        return cls([s.sign for s in servos], [s.gear for s in servos], zero,
                   [s.limits for s in servos] if servos else np.zeros((0, 2)),
                   [MODELS[s.model].ticks_per_turn for s in servos] or TICKS_PER_TURN)

    def __len__(self) -> int:
        return len(self.zero)

    def angles(self, ticks, out=None, clamp: bool = True) -> np.ndarray:
        """Joint radians from raw ticks: (k,) or (N, k) ticks -> float64 of the same shape,
        wrapped, clamped to the limits unless ``clamp`` is False. With (k,) ticks and ``out``
        given this allocates nothing (the per-frame path)."""
        ticks = np.asarray(ticks)
        work = self._work if ticks.shape == self._work.shape else np.empty(ticks.shape)
        if out is None:
            out = np.empty(ticks.shape)
        np.subtract(ticks, self.zero, out=work)
        np.multiply(work, self.radians_per_tick, out=out)
        if self._any_wrap:  # x -> top - ((top - x) mod 2π), into (top - 2π, top]
            np.subtract(self._top, out, out=work)
            np.remainder(work, 2.0 * np.pi, out=work)
            np.subtract(self._top, work, out=work)
            np.copyto(out, work, where=self._wrap)
        if clamp:
            np.clip(out, self.lo, self.hi, out=out)
        return out

    def ticks(self, angles, out=None) -> np.ndarray:
        """Float ticks at joint ``angles`` (radians, (k,) or (N, k)): the inverse of
        :meth:`angles` (no wrap, no clamp). Allocation-free with ``out`` given."""
        if out is None:
            out = np.empty(np.shape(angles))
        np.divide(angles, self.radians_per_tick, out=out)
        out += self.zero
        return out

    def tick_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float ticks of the joint limits, lo <= hi per servo (a sign -1 swaps them)."""
        a, b = self.ticks(self.lo), self.ticks(self.hi)
        return np.minimum(a, b), np.maximum(a, b)

    def joint_degrees(self, ticks) -> np.ndarray:
        """Absolute joint degrees of tick differences ((k,) or (N, k))."""
        return np.abs(np.asarray(ticks, float)) / self.ticks_per_joint_degree

    def servo_degrees(self, ticks) -> np.ndarray:
        """Absolute degrees of the servo shaft of tick differences ((k,) or (N, k))."""
        return np.abs(np.asarray(ticks, float)) / ticks_per_degree(self.ticks_per_turn)

