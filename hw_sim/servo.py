"""One simulated servo: its control table (bytes), reads/writes with the real error rules, and its
behaviour in time (motion source with torque off; with torque on, velocity-based or time-based
(Drive Mode bit 2) profile motion in position modes 3/4/5 and constant Goal Velocity in mode 1;
ticks, reboot).

Actuation: Present Current rises with acceleration, speed and an external load (``load_ma``);
a demand above the motor's current for ``OVERLOAD_S`` latches the overload error; Present
Temperature follows the current (I² heating, first-order cooling; ``heat_gain`` speeds it up);
Moving / Moving Status; the Bus Watchdog (98, 20 ms units, active while torque is on): when
nothing reaches the servo for longer, it stops where it is, the item reads -1 and Goal
Position / Velocity / PWM / Current writes get a data range error until it is written 0;
Drive Mode bit 3 (torque on by goal update).

Every address comes from the model's table by item name (``_Items``), so one class serves the
three layouts of ``hw_sim.control_table``. The X layout (X-series, MX(2.0)) has the operating
modes, multi-turn counting, Homing Offset, Drive Mode, Bus Watchdog and indirect items above.
The single-turn layouts (AX / RX / MX on Protocol 1.0, XL-320) have joint mode (Goal Position
inside CW..CCW Angle Limit, at Moving Speed; MX: Goal Acceleration) and wheel mode (both limits
0, XL-320 Control Mode 1: turn at Moving Speed, bit 10 = clockwise); Present Speed / Present
Load are sign-magnitude (bit 10 = clockwise); on Protocol 1.0 the EEPROM (0..23) is written
with torque on unless Lock (47) is 1, and hardware errors are kept by the servo (there is no
Hardware Error Status item) and reported in every status packet's error byte.

Not modelled: reverse direction (bit 0), current/PWM dynamics (modes 0 and 16 hold still),
per-mode gain resets, compliance, multi-turn mode of MX on Protocol 1.0.

Positions: ``shaft`` is the physical shaft angle as a continuous count of 4096 per turn (the
unit of the motion sources, 2048 = the middle of the range). X layout: Present Position = shaft
- base + Homing Offset, where ``base`` (a multiple of 4096) is re-chosen at boot, reboot, Clear
and torque-on in position mode ("re-basing"). Single-turn layouts: the angle within the turn,
in the model's own ticks around its middle (MX 2048 of 0..4095; AX / RX / XL-320 512 of
0..1023 over 300°, a reading in the 60° dead zone reads the nearer end, 0 or 1023).
"""

from __future__ import annotations

import math
import random

from hw_sim import codec
from hw_sim.control_table import (IDLE_TEMPERATURE, NOMINAL_VOLTAGE, OPERATING_MODES,
                                  PROTOCOL_2, TICKS_PER_TURN, VELOCITY_UNIT_RPM, Field,
                                  ServoModel, from_shaft, to_shaft)

TICKS_PER_REV = TICKS_PER_TURN
VELOCITY_UNIT_TICKS_S = VELOCITY_UNIT_RPM / 60.0 * TICKS_PER_REV  # one 0.229 rpm unit in ticks/s
ACCEL_UNIT_TICKS_S2 = 214.577 / 3600.0 * TICKS_PER_REV  # one 214.577 rev/min^2 unit in ticks/s^2
GOAL_ACCEL_UNIT_TICKS_S2 = 8.583 / 360.0 * TICKS_PER_REV  # MX Goal Acceleration: 8.583 deg/s^2
MOVING_SPEED_MAX = 1023  # Moving Speed 0 = as fast as the motor turns: taken as this many units

# Hardware Error Status (70) bits.
HW_ERROR_BITS = {"input_voltage": 0x01, "overheating": 0x04, "encoder": 0x08,
                 "electrical_shock": 0x10, "overload": 0x20}

# Actuation model (see the module docstring). Currents in mA, temperatures in deg C.
IDLE_CURRENT_MA = 60.0
CURRENT_PER_ACCEL = 0.0002     # mA per tick/s^2
CURRENT_PER_SPEED = 0.02       # mA per tick/s
OVERLOAD_S = 1.0               # seconds of demand above the motor's current before it latches
CURRENT_TAU_S = 0.05           # the winding and shaft smooth the current (first order): a velocity
                               # step seen over a tiny refresh interval is not a sustained current
HEATING_C_PER_S_A2 = 0.4       # deg C per second per A^2
COOLING_TAU_S = 120.0          # first-order cooling time constant
WATCHDOG_UNIT_S = 0.020        # Bus Watchdog unit
WATCHDOG_TRIPPED = 0xFF        # the item's raw byte after a trip (-1)
DIRECTION_BIT = 1 << 10        # sign-magnitude items: bit 10 set = clockwise


class _Items:
    """The fields one servo's behaviour uses, looked up by name in its model's table (None: the
    model has no such item)."""

    NAMES = {
        "firmware": ("Firmware Version",), "id": ("ID",), "baud": ("Baud Rate",),
        "delay": ("Return Delay Time",), "drive": ("Drive Mode",),
        "mode": ("Operating Mode", "Control Mode"), "secondary": ("Secondary ID",),
        "homing": ("Homing Offset",), "threshold": ("Moving Threshold",),
        "temp_limit": ("Temperature Limit",), "current_limit": ("Current Limit",),
        "velocity_limit": ("Velocity Limit",), "max_pos": ("Max Position Limit", "CCW Angle Limit"),
        "min_pos": ("Min Position Limit", "CW Angle Limit"), "shutdown": ("Shutdown",),
        "torque": ("Torque Enable",), "level": ("Status Return Level",),
        "registered": ("Registered Instruction", "Registered"),
        "hw_error": ("Hardware Error Status",), "watchdog": ("Bus Watchdog",),
        "goal_velocity": ("Goal Velocity",), "profile_acc": ("Profile Acceleration",),
        "speed": ("Profile Velocity", "Moving Speed"), "goal_acc": ("Goal Acceleration",),
        "goal": ("Goal Position",), "tick": ("Realtime Tick",), "moving": ("Moving",),
        "moving_status": ("Moving Status",), "load": ("Present Current", "Present Load"),
        "current": ("Current",), "velocity": ("Present Velocity", "Present Speed"),
        "position": ("Present Position",), "velocity_traj": ("Velocity Trajectory",),
        "position_traj": ("Position Trajectory",),
        "voltage": ("Present Input Voltage", "Present Voltage"),
        "temperature": ("Present Temperature",), "lock": ("Lock",),
    }

    def __init__(self, model: ServoModel) -> None:
        for key, names in self.NAMES.items():
            setattr(self, key, next((model.by_name[n] for n in names if n in model.by_name), None))
        self.goals = tuple(f.addr for f in (model.by_name.get(n) for n in (
            "Goal PWM", "Goal Current", "Goal Velocity", "Goal Position")) if f)


def _addr_map(model: ServoModel) -> list:
    """address -> (Field, offset within field) or None for undefined bytes."""
    amap: list = [None] * model.size
    for f in model.fields:
        for k in range(f.size):
            amap[f.addr + k] = (f, k)
    return amap


def _sign_magnitude(value: int) -> int:
    """A signed count as Protocol 1.0 / XL-320 Present Speed / Load: |value| (at most 1023),
    bit 10 set when negative (clockwise)."""
    return min(abs(value), 1023) | (DIRECTION_BIT if value < 0 else 0)


class Servo:
    """A simulated servo.

    model: its ServoModel; joint: the physical joint key its motion source is asked about (the
    id it was created with; it does not change when the ID item is rewritten).
    """

    def __init__(self, model: ServoModel, dxl_id: int, *, motion, now: float = 0.0,
                 baud_index: int | None = None, return_delay: int | None = None,
                 rng: random.Random | None = None) -> None:
        self.model = model
        self.spec = model.spec  # the model's units, current, Bus Watchdog (MODEL_SPECS row)
        self.it = it = _Items(model)
        self.multi_turn = it.homing is not None  # the X layout
        # Shaft ticks (4096 per turn) per second for one unit of Present / Profile velocity.
        self._velocity_unit = self.spec.velocity_unit_rpm / 60.0 * TICKS_PER_TURN
        rw = [f for f in model.fields if not f.eeprom and not f.writable]
        self._dynamic = (min(f.addr for f in rw), max(f.addr + f.size for f in rw))
        self.joint = dxl_id
        self.motion = motion
        self.mem = bytearray(model.size)
        self._amap = _addr_map(model)
        self._rng = rng or random.Random(dxl_id)
        for f in model.fields:
            self._store(f, f.default)
        self._store(it.id, dxl_id)
        if baud_index is not None:
            self._store(it.baud, baud_index)
        if return_delay is not None:
            self._store(it.delay, return_delay)
        self.eeprom_defaults = bytearray(model.eeprom_end)  # what Factory Reset restores
        for f in model.fields:
            if f.eeprom:
                self._store_into(self.eeprom_defaults, f, f.default)
        self.hw_error = 0
        self.powered = True
        self.noise = 0  # +- ticks of Present Position jitter (fault "noise")
        self.temperature = float(IDLE_TEMPERATURE)
        self.voltage = NOMINAL_VOLTAGE.get(model.name, 50)
        self.registered: tuple[int, bytes] | None = None
        self.load_ma = 0.0    # external load on the shaft (fault "load"), mA to hold it
        self.heat_gain = 1.0  # heating speed factor (fault "load" heat=)
        self._boot(now)

    # ---- raw control-table access -------------------------------------------------------
    @staticmethod
    def _store_into(mem: bytearray, f: Field, value: int) -> None:
        mem[f.addr:f.addr + f.size] = int(value).to_bytes(f.size, "little", signed=value < 0)

    def _store(self, f: Field, value: int) -> None:
        self._store_into(self.mem, f, value)

    def _val(self, f: Field | None, default: int = 0) -> int:
        """The value of item ``f`` (signed where it is), ``default`` when the model has none."""
        if f is None:
            return default
        return int.from_bytes(self.mem[f.addr:f.addr + f.size], "little", signed=f.signed)

    def _put(self, f: Field | None, value: int) -> None:
        """Store a read-only item's new value, clipped to its size (nothing if it has none)."""
        if f is None:
            return
        lo, hi = f.bounds
        value = int(value)
        value = lo if value < lo else hi if value > hi else value
        self.mem[f.addr:f.addr + f.size] = value.to_bytes(f.size, "little", signed=value < 0)

    def get(self, name: str) -> int:
        """The current value of item ``name`` (signed where it is), refreshed first."""
        f = self.model.field(name)
        if f.addr + f.size > self._dynamic[0] and f.addr < self._dynamic[1]:
            self.refresh(self.now)
        return self._val(f)

    def set(self, name: str, value: int) -> None:
        """Store ``value`` in item ``name`` directly (test setup; no access rules)."""
        self._store(self.model.field(name), value)

    def _get_raw(self, addr: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self.mem[addr:addr + size], "little", signed=signed)

    @property
    def dxl_id(self) -> int:
        return self._val(self.it.id)

    @property
    def baud_index(self) -> int:
        return self._val(self.it.baud)

    @property
    def return_delay(self) -> int:
        return self._val(self.it.delay)

    @property
    def firmware(self) -> int:
        return self._val(self.it.firmware)

    @property
    def secondary_id(self) -> int | None:
        """Secondary ID when set (0..252), else None (also on models without one)."""
        value = self._val(self.it.secondary, 255)
        return value if value <= 252 else None

    @property
    def torque(self) -> bool:
        return self._val(self.it.torque) == 1

    @property
    def return_delay_s(self) -> float:
        return self.return_delay * 2e-6

    @property
    def status_return_level(self) -> int:
        return self._val(self.it.level)

    @property
    def hardware_error(self) -> int:
        return self.hw_error

    @property
    def registered_flag(self) -> int:
        return self._val(self.it.registered)

    @registered_flag.setter
    def registered_flag(self, value: int) -> None:
        self._store(self.it.registered, value)

    # ---- boot / reboot -------------------------------------------------------------------
    def _boot(self, now: float) -> None:
        """Power-up: RAM defaults, Realtime Tick from 0, Present Position re-based."""
        for f in self.model.fields:
            if not f.eeprom:
                self._store(f, f.default)
        self.hw_error = 0
        self.boot_t = now
        self.now = now
        self.registered = None
        self.shaft = float(self.motion.position(self.joint, now))
        self.velocity = 0.0  # ticks/s
        self._last_velocity = 0.0
        self._last_t = now
        self._last_shaft = self.shaft
        self._rebase()
        self.temperature = float(IDLE_TEMPERATURE)
        self.current_ma = 0.0
        self.overload_s = 0.0
        self.heard_t = now
        self._traj: tuple[float, float, float, float, float] | None = None
        self.refresh(now)

    def reboot(self, now: float) -> None:
        """Reboot instruction: the same as a power cycle (RAM defaults, re-based position)."""
        self._boot(now)

    def power_off(self) -> None:
        self.powered = False

    def power_on(self, now: float) -> None:
        self.powered = True
        self._boot(now)

    def factory_reset(self, option: int, now: float) -> None:
        """Factory Reset: 0xFF all, 0x01 all but ID, 0x02 all but ID and baud; then reboot."""
        keep_id, keep_baud = self.dxl_id, self.baud_index
        self.mem[:self.model.eeprom_end] = self.eeprom_defaults
        if option in (0x01, 0x02):
            self._store(self.it.id, keep_id)
        if option == 0x02:
            self._store(self.it.baud, keep_baud)
        self._boot(now)

    def _rebase(self) -> None:
        self.base = math.floor(self.shaft / TICKS_PER_TURN) * TICKS_PER_TURN

    def latch_hardware_error(self, bits: int) -> None:
        """Set hardware error bits; torque goes off when Shutdown enables one of them."""
        self.hw_error |= bits
        self._put(self.it.hw_error, self.hw_error)
        if bits & self._val(self.it.shutdown):
            self._store(self.it.torque, 0)

    # ---- positions -----------------------------------------------------------------------
    def _present_position(self) -> int:
        if self.multi_turn:
            pos = int(round(self.shaft)) - self.base + self._val(self.it.homing)
        else:
            own = from_shaft(self.spec, self.shaft - math.floor(self.shaft / TICKS_PER_TURN) * TICKS_PER_TURN)
            top = self.spec.position_ticks
            pos = int(round(own)) % top if self.spec.position_range_deg == 360.0 \
                else max(0, min(top - 1, int(round(own))))
        if self.noise:
            pos += self._rng.randint(-self.noise, self.noise)
        return pos

    def _goal_shaft(self) -> float:
        """The shaft count Goal Position asks for (in the turn chosen at the last re-base)."""
        goal = self._val(self.it.goal)
        if self.multi_turn:
            return float(goal - self._val(self.it.homing) + self.base)
        return self.base + to_shaft(self.spec, goal)

    def _wheel_mode(self) -> bool:
        """Single-turn layouts: Protocol 1.0 with both angle limits 0, XL-320 Control Mode 1."""
        if self.it.mode is not None:
            return self._val(self.it.mode) == 1
        return self._val(self.it.min_pos) == 0 and self._val(self.it.max_pos) == 0

    def _position_control(self) -> bool:
        if self.multi_turn:
            return self._val(self.it.mode) in (3, 4, 5)
        return not self._wheel_mode()

    # ---- time ----------------------------------------------------------------------------
    def refresh(self, now: float) -> None:
        """Advance behaviour to ``now`` (seconds) and update the read-only RAM items."""
        it = self.it
        torque = self.torque
        wd = self._val(it.watchdog) & 0xFF
        if torque and 0 < wd < 0x80 and self.powered:
            trip_t = self.heard_t + wd * WATCHDOG_UNIT_S
            if now > trip_t:
                if trip_t > self._last_t:
                    self.refresh(trip_t)
                self._watchdog_trip()
        dt = now - self._last_t
        self.now = now
        if self.powered and dt > 0:
            if torque:
                if self._position_control():
                    self._profile_step(dt, now)
                elif self.multi_turn and self._val(it.mode) == 1:  # velocity: turn at Goal Velocity
                    self.velocity = self._val(it.goal_velocity) * self._velocity_unit
                    self.shaft += self.velocity * dt
                elif not self.multi_turn:  # wheel mode: turn at Moving Speed (bit 10 = CW)
                    raw = self._val(it.speed)
                    units = (raw & 0x3FF) * (-1 if raw & DIRECTION_BIT else 1)
                    self.velocity = units * self._velocity_unit
                    self.shaft += self.velocity * dt
                else:  # current / PWM control with no load model: the shaft stays put
                    self.velocity = 0.0
            else:
                self.shaft = float(self.motion.position(self.joint, now))
                self.velocity = (self.shaft - self._last_shaft) / dt if dt > 1e-4 else self.velocity
            accel = abs(self.velocity - self._last_velocity) / dt
            self._last_t = now
            self._last_shaft = self.shaft
            self._last_velocity = self.velocity
            self._actuation_step(dt, accel)
        vel_units = int(round(self.velocity / self._velocity_unit))
        moving = 1 if abs(vel_units) > self._val(it.threshold, 1) else 0
        pos = self._present_position()
        self._put(it.tick, int((now - self.boot_t) * 1000.0) % 32768)
        self._put(it.moving, moving)
        self._put(it.position, pos)
        if self.multi_turn:
            self._put(it.velocity, vel_units)
        else:
            self._put(it.velocity, _sign_magnitude(vel_units))
        if it.moving_status is not None:
            if torque:
                goal = self._val(it.goal)
                ongoing = moving or (self._traj is not None and now < self._traj[0] + self._traj[3])
                kind = 0x30 if self._val(it.profile_acc) else 0x10
                self.mem[it.moving_status.addr] = ((0x01 if abs(goal - pos) <= 1 and not ongoing else 0)
                                                   | (0x02 | kind if ongoing else 0))
                self._put(it.velocity_traj, vel_units)
                self._put(it.position_traj, pos)
            else:
                self.mem[it.moving_status.addr] = 0
        unit = self.spec.current_unit_ma  # None: Present Load, 0.1 % of the motor's current
        load = int(round(1000.0 * self.current_ma / self.spec.motor_current_ma))
        if self.multi_turn:
            self._put(it.load, int(round(self.current_ma / unit)) if unit else load)
        else:
            self._put(it.load, _sign_magnitude(load))
            if it.current is not None:  # MX-64 / MX-106 on Protocol 1.0: 2048 = 0 A
                self._put(it.current, 2048 + int(round(self.current_ma / unit)))
        self._put(it.voltage, int(self.voltage))
        self._put(it.temperature, int(self.temperature))

    def _actuation_step(self, dt: float, accel: float) -> None:
        """Present Current, overload and temperature over ``dt`` s at ``accel`` ticks/s^2."""
        stall = self.spec.motor_current_ma
        if self.torque:
            demand = (IDLE_CURRENT_MA + CURRENT_PER_ACCEL * accel
                      + CURRENT_PER_SPEED * abs(self.velocity) + self.load_ma)
            unit = self.spec.current_unit_ma
            limit = self._val(self.it.current_limit) * unit \
                if unit is not None and self.it.current_limit is not None else stall
            limit = min(limit, stall)
            if demand > limit:
                self.overload_s += dt
            else:
                self.overload_s = max(0.0, self.overload_s - dt)
            settle = 1.0 - math.exp(-dt / CURRENT_TAU_S)
            self.current_ma += (min(demand, limit) - self.current_ma) * settle
            if self.overload_s > OVERLOAD_S:
                self.latch_hardware_error(0x20)
        else:
            self.current_ma = 0.0
            self.overload_s = 0.0
        amps = self.current_ma / 1000.0
        heating = HEATING_C_PER_S_A2 * self.heat_gain * amps * amps
        cooling = (self.temperature - IDLE_TEMPERATURE) / COOLING_TAU_S
        self.temperature = min(self.temperature + dt * (heating - cooling), 150.0)
        if self.temperature > self._val(self.it.temp_limit) and not self.hw_error & 0x04:
            self.latch_hardware_error(0x04)

    def _watchdog_trip(self) -> None:
        """The host fell silent past the Bus Watchdog: stop here, hold, refuse goals."""
        self.mem[self.it.watchdog.addr] = WATCHDOG_TRIPPED
        self._traj = None
        self.velocity = 0.0
        self._store(self.it.goal, self._present_position())

    def hear(self, now: float) -> None:
        """An instruction reached this servo at ``now``: advance, then restart the watchdog."""
        self.refresh(now)
        self.heard_t = now

    def _start_time_profile(self, now: float) -> None:
        """A new Goal Position under a time-based profile (Drive Mode bit 2): the move takes
        Profile Velocity ms, accelerating for Profile Acceleration ms (at most half of it)."""
        total = self._val(self.it.speed) / 1000.0
        if total <= 0:
            self._traj = None
            return
        ramp = min(self._val(self.it.profile_acc) / 1000.0, total / 2.0)
        self._traj = (now, self.shaft, self._goal_shaft(), total, ramp)

    def _time_profile_at(self, now: float) -> tuple[float, float]:
        """(shaft, velocity) of the time-based trajectory at ``now``."""
        t0, p0, p1, total, ramp = self._traj
        tau = min(max(now - t0, 0.0), total)
        dist = p1 - p0
        vpeak = dist / (total - ramp)
        if ramp > 0 and tau < ramp:
            return p0 + 0.5 * vpeak / ramp * tau * tau, vpeak * tau / ramp
        if tau < total - ramp or ramp == 0:
            if tau >= total:
                return p1, 0.0
            return p0 + vpeak * (tau - 0.5 * ramp), vpeak
        rest = total - tau
        return p1 - 0.5 * vpeak / ramp * rest * rest, vpeak * rest / ramp

    def _profile_step(self, dt: float, now: float | None = None) -> None:
        """Move the shaft toward Goal Position under Profile Velocity / Acceleration (single-
        turn layouts: Moving Speed, MX Goal Acceleration)."""
        if self._traj is not None and now is not None:
            self.shaft, self.velocity = self._time_profile_at(now)
            if now >= self._traj[0] + self._traj[3]:
                self._traj = None
            return
        target = self._goal_shaft()
        speed = self._val(self.it.speed)
        if self.multi_turn:
            pa = self._val(self.it.profile_acc)
            vmax = (speed or max(self._val(self.it.velocity_limit), 1)) * self._velocity_unit
            amax = pa * ACCEL_UNIT_TICKS_S2 if pa else math.inf
        else:
            ga = self._val(self.it.goal_acc)
            vmax = ((speed & 0x3FF) or MOVING_SPEED_MAX) * self._velocity_unit
            amax = ga * GOAL_ACCEL_UNIT_TICKS_S2 if ga else math.inf
        err = target - self.shaft
        steps = max(1, int(dt / 0.001))
        h = dt / steps
        v = self.velocity
        for _ in range(steps):
            err = target - self.shaft
            if abs(err) < 0.5 and abs(v) * h < 1.0:
                self.shaft, v = float(target), 0.0
                break
            stop = math.sqrt(2.0 * amax * abs(err)) if amax != math.inf else math.inf
            v_des = math.copysign(min(vmax, stop, abs(err) / h), err)
            dv = v_des - v
            if amax != math.inf and abs(dv) > amax * h:
                dv = math.copysign(amax * h, dv)
            v += dv
            self.shaft += v * h
        self.velocity = v

    # ---- protocol-level reads and writes ------------------------------------------------
    def read(self, addr: int, length: int, now: float) -> tuple[int, bytes]:
        """(error, data) for a Read of ``length`` bytes at ``addr``; data empty on error."""
        end = addr + length
        self.hear(now)  # refreshes every read-only item to ``now``: the read sees them fresh
        if length == 0 or end > self.model.size:
            return codec.ERR_ACCESS, b""
        data = bytes(self.mem[addr:end])
        for a_item, d_item, count in self.model.indirect:
            if addr < d_item + count and end > d_item:
                data = bytearray(data)
                for k in range(max(addr, d_item), min(end, d_item + count)):
                    target = self._get_raw(a_item + 2 * (k - d_item), 2)
                    data[k - addr] = self.mem[target] if target < self.model.size else 0
                data = bytes(data)
        return 0, data

    def check_write(self, addr: int, data: bytes) -> int:
        """The error a Write of ``data`` at ``addr`` would get (0 if it is accepted), as a
        Protocol 2.0 error number (``hw_sim.codec1.error_byte`` maps it for Protocol 1.0)."""
        end = addr + len(data)
        if not data or end > self.model.size:
            return codec.ERR_ACCESS
        it, amap = self.it, self._amap
        p2 = self.model.protocol == PROTOCOL_2
        k = addr
        while k < end:
            entry = amap[k]
            if entry is None:
                return codec.ERR_ACCESS
            f, off = entry
            if off != 0 or f.addr + f.size > end:
                return codec.ERR_DATA_LENGTH
            if not f.writable:
                return codec.ERR_ACCESS
            if f.eeprom and (self.torque if p2 else self._val(it.lock)):
                return codec.ERR_ACCESS  # EEPROM: torque on (2.0), Lock set (1.0)
            if f is it.watchdog:
                first = self.spec.bus_watchdog_firmware
                if first is None or self.firmware < first:
                    return codec.ERR_ACCESS  # firmware without the Bus Watchdog
            if f.addr in it.goals and it.watchdog is not None \
                    and self.mem[it.watchdog.addr] == WATCHDOG_TRIPPED:
                return codec.ERR_DATA_RANGE  # refused until the watchdog is cleared
            value = int.from_bytes(data[k - addr:k - addr + f.size], "little", signed=f.signed)
            if f.lo is not None and not f.lo <= value <= f.hi:
                return codec.ERR_DATA_RANGE
            if f is it.mode and self.multi_turn \
                    and value not in OPERATING_MODES.get(self.model.name, {value}):
                return codec.ERR_DATA_RANGE
            if f is it.goal and (self._val(it.mode) == 3 if self.multi_turn else not self._wheel_mode()):
                if not self._val(it.min_pos) <= value <= self._val(it.max_pos):
                    return codec.ERR_DATA_LIMIT  # Protocol 1.0: the angle limit error
            k += f.size
        return 0

    def write(self, addr: int, data: bytes, now: float) -> int:
        """Apply a Write (all-or-nothing); returns the error number (0 = done)."""
        self.hear(now)
        err = self.check_write(addr, data)
        if err:
            return err
        it = self.it
        end = addr + len(data)
        goal_written = addr <= it.goal.addr < end
        torque_before, mode_before = self.torque, self._val(it.mode)
        t = it.torque.addr
        if addr <= t < end and data[t - addr] == 1 and self.hw_error:
            data = bytearray(data)
            data[t - addr] = 0  # a latched hardware error keeps torque off until reboot
        for a_item, d_item, count in self.model.indirect:
            if addr < d_item + count and end > d_item:
                for k in range(max(addr, d_item), min(end, d_item + count)):
                    target = self._get_raw(a_item + 2 * (k - d_item), 2)
                    entry = self._amap[target] if target < self.model.size else None
                    if entry is not None and entry[0].writable and not entry[0].eeprom:
                        self.mem[target] = data[k - addr]
        self.mem[addr:end] = data
        if self.multi_turn and self._val(it.mode) != mode_before:
            self._rebase()
            self._store(it.profile_acc, 0)
            self._store(it.speed, 0)
        if self.torque and not torque_before:
            if not self.multi_turn or self._val(it.mode) == 3:
                self._rebase()
            self.velocity = 0.0
            # The servo holds where it is: Goal Position takes Present Position (no jump).
            if not goal_written:
                self._store(it.goal, self._present_position())
        if (self._val(it.drive) & 0x08) and goal_written and not self.torque and not self.hw_error:
            self._store(it.torque, 1)  # Drive Mode bit 3: Torque On by Goal Update
            self.velocity = 0.0
        if not self.torque:
            self._traj = None
        elif goal_written and self._val(it.drive) & 0x04 and self._val(it.mode) in (3, 4, 5):
            self._start_time_profile(now)
        self.refresh(now)
        return 0

    def clear_multi_turn(self, now: float) -> int:
        """Clear instruction: re-base Present Position into one turn; Result Fail if moving."""
        self.refresh(now)
        if self._val(self.it.moving):
            return codec.ERR_RESULT_FAIL
        self._rebase()
        self.refresh(now)
        return 0
