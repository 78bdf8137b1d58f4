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

Not modelled: reverse direction (bit 0), current/PWM dynamics (modes 0 and 16 hold still),
per-mode gain resets.

Positions are encoder counts (4096 per turn). ``shaft`` is the physical shaft angle as a
continuous count; Present Position = shaft - base + Homing Offset, where ``base`` (a multiple of
4096) is re-chosen at boot, reboot, Clear and torque-on in position mode ("re-basing").
"""

from __future__ import annotations

import math
import random

from hw_sim import codec
from hw_sim.control_table import (EEPROM_END, IDLE_TEMPERATURE, NOMINAL_VOLTAGE, OPERATING_MODES,
                                  TICKS_PER_TURN, VELOCITY_UNIT_RPM, Field, ServoModel)

TICKS_PER_REV = TICKS_PER_TURN
VELOCITY_UNIT_TICKS_S = VELOCITY_UNIT_RPM / 60.0 * TICKS_PER_REV  # one 0.229 rpm unit in ticks/s
ACCEL_UNIT_TICKS_S2 = 214.577 / 3600.0 * TICKS_PER_REV  # one 214.577 rev/min^2 unit in ticks/s^2

# Hardware Error Status (70) bits.
HW_ERROR_BITS = {"input_voltage": 0x01, "overheating": 0x04, "encoder": 0x08,
                 "electrical_shock": 0x10, "overload": 0x20}

_DYNAMIC_START, _DYNAMIC_END = 120, 148  # Realtime Tick .. Backup Ready

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
_GOAL_ADDRS = (100, 102, 104, 116)  # Goal PWM, Current, Velocity, Position


def _addr_map(model: ServoModel) -> list:
    """address -> (Field, offset within field) or None for undefined bytes."""
    amap: list = [None] * model.size
    for f in model.fields:
        for k in range(f.size):
            amap[f.addr + k] = (f, k)
    return amap


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
        self._velocity_unit = self.spec.velocity_unit_rpm / 60.0 * self.spec.ticks_per_turn
        self.joint = dxl_id
        self.motion = motion
        self.mem = bytearray(model.size)
        self._amap = _addr_map(model)
        self._rng = rng or random.Random(dxl_id)
        for f in model.fields:
            self._store(f, f.default)
        self._store(model.field("ID"), dxl_id)
        if baud_index is not None:
            self._store(model.field("Baud Rate"), baud_index)
        if return_delay is not None:
            self._store(model.field("Return Delay Time"), return_delay)
        self.eeprom_defaults = bytearray(EEPROM_END)  # what Factory Reset restores
        for f in model.fields:
            if f.eeprom:
                self._store_into(self.eeprom_defaults, f, f.default)
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

    def get(self, name: str) -> int:
        """The current value of item ``name`` (signed where the item is), refreshed first."""
        f = self.model.field(name)
        if f.addr >= _DYNAMIC_START:
            self.refresh(self.now)
        return int.from_bytes(self.mem[f.addr:f.addr + f.size], "little", signed=f.signed)

    def set(self, name: str, value: int) -> None:
        """Store ``value`` in item ``name`` directly (test setup; no access rules)."""
        self._store(self.model.field(name), value)

    def _get_raw(self, addr: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self.mem[addr:addr + size], "little", signed=signed)

    @property
    def dxl_id(self) -> int:
        return self.mem[7]

    @property
    def torque(self) -> bool:
        return self.mem[64] == 1

    @property
    def return_delay_s(self) -> float:
        return self.mem[9] * 2e-6

    @property
    def status_return_level(self) -> int:
        return self.mem[68]

    @property
    def hardware_error(self) -> int:
        return self.mem[70]

    @property
    def alert(self) -> int:
        return codec.ALERT if self.mem[70] else 0

    # ---- boot / reboot -------------------------------------------------------------------
    def _boot(self, now: float) -> None:
        """Power-up: RAM defaults, Realtime Tick from 0, Present Position re-based."""
        for f in self.model.fields:
            if not f.eeprom:
                self._store(f, f.default)
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
        keep_id, keep_baud = self.mem[7], self.mem[8]
        self.mem[:EEPROM_END] = self.eeprom_defaults
        if option in (0x01, 0x02):
            self.mem[7] = keep_id
        if option == 0x02:
            self.mem[8] = keep_baud
        self._boot(now)

    def _rebase(self) -> None:
        self.base = math.floor(self.shaft / TICKS_PER_TURN) * TICKS_PER_TURN

    def latch_hardware_error(self, bits: int) -> None:
        """Set Hardware Error Status bits; torque goes off when Shutdown enables one of them."""
        self.mem[70] |= bits
        if bits & self.mem[63]:
            self.mem[64] = 0

    # ---- time ----------------------------------------------------------------------------
    def _present_position(self) -> int:
        homing = self._get_raw(20, 4, True)
        pos = int(round(self.shaft)) - self.base + homing
        if self.noise:
            pos += self._rng.randint(-self.noise, self.noise)
        return pos

    def refresh(self, now: float) -> None:
        """Advance behaviour to ``now`` (seconds) and update the read-only RAM items."""
        mem = self.mem
        if mem[64] and 0 < mem[98] < 0x80 and self.powered:
            trip_t = self.heard_t + mem[98] * WATCHDOG_UNIT_S
            if now > trip_t:
                if trip_t > self._last_t:
                    self.refresh(trip_t)
                self._watchdog_trip()
        dt = now - self._last_t
        self.now = now
        if self.powered and dt > 0:
            if mem[64]:
                mode = mem[11]
                if mode in (3, 4, 5):
                    self._profile_step(dt, now)
                elif mode == 1:  # velocity control: turn at Goal Velocity
                    self.velocity = self._get_raw(104, 4, True) * self._velocity_unit
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
        tick = int((now - self.boot_t) * 1000.0) % 32768
        vel_units = int(round(self.velocity / self._velocity_unit))
        moving = 1 if abs(vel_units) > self._get_raw(24, 4) else 0
        pos = self._present_position()
        mem[120:122] = tick.to_bytes(2, "little")
        mem[122] = moving
        mem[128:132] = vel_units.to_bytes(4, "little", signed=True)
        mem[132:136] = pos.to_bytes(4, "little", signed=True)
        if mem[64]:
            goal = self._get_raw(116, 4, True)
            ongoing = moving or (self._traj is not None and now < self._traj[0] + self._traj[3])
            kind = 0x30 if self._get_raw(108, 4) else 0x10
            mem[123] = ((0x01 if abs(goal - pos) <= 1 and not ongoing else 0)
                        | (0x02 | kind if ongoing else 0))
            mem[136:140] = vel_units.to_bytes(4, "little", signed=True)
            mem[140:144] = pos.to_bytes(4, "little", signed=True)
        else:
            mem[123] = 0
        unit = self.spec.current_unit_ma  # None: Present Load, 0.1 % of the motor's current
        present = (int(round(self.current_ma / unit)) if unit
                   else int(round(1000.0 * self.current_ma / self.spec.motor_current_ma)))
        present = max(-32768, min(32767, present))
        mem[126:128] = present.to_bytes(2, "little", signed=True)
        mem[144:146] = int(self.voltage).to_bytes(2, "little")
        mem[146] = max(0, min(255, int(self.temperature)))

    def _actuation_step(self, dt: float, accel: float) -> None:
        """Present Current, overload and temperature over ``dt`` s at ``accel`` ticks/s^2."""
        stall = self.spec.motor_current_ma
        if self.mem[64]:
            demand = (IDLE_CURRENT_MA + CURRENT_PER_ACCEL * accel
                      + CURRENT_PER_SPEED * abs(self.velocity) + self.load_ma)
            unit = self.spec.current_unit_ma
            limit = self._get_raw(38, 2) * unit if unit is not None else stall
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
        if self.temperature > self.mem[31] and not self.mem[70] & 0x04:
            self.latch_hardware_error(0x04)

    def _watchdog_trip(self) -> None:
        """The host fell silent past the Bus Watchdog: stop here, hold, refuse goals."""
        self.mem[98] = WATCHDOG_TRIPPED
        self._traj = None
        self.velocity = 0.0
        self.mem[116:120] = self._present_position().to_bytes(4, "little", signed=True)

    def hear(self, now: float) -> None:
        """An instruction reached this servo at ``now``: advance, then restart the watchdog."""
        self.refresh(now)
        self.heard_t = now

    def _start_time_profile(self, now: float) -> None:
        """A new Goal Position under a time-based profile (Drive Mode bit 2): the move takes
        Profile Velocity ms, accelerating for Profile Acceleration ms (at most half of it)."""
        total = self._get_raw(112, 4) / 1000.0
        if total <= 0:
            self._traj = None
            return
        ramp = min(self._get_raw(108, 4) / 1000.0, total / 2.0)
        target = self._get_raw(116, 4, True) - self._get_raw(20, 4, True) + self.base
        self._traj = (now, self.shaft, float(target), total, ramp)

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
        """Move the shaft toward Goal Position under Profile Velocity / Acceleration."""
        if self._traj is not None and now is not None:
            self.shaft, self.velocity = self._time_profile_at(now)
            if now >= self._traj[0] + self._traj[3]:
                self._traj = None
            return
        homing = self._get_raw(20, 4, True)
        target = self._get_raw(116, 4, True) - homing + self.base
        pv = self._get_raw(112, 4)
        pa = self._get_raw(108, 4)
        vmax = (pv or max(self._get_raw(44, 4), 1)) * self._velocity_unit
        amax = pa * ACCEL_UNIT_TICKS_S2 if pa else math.inf
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
        self.hear(now)
        if length == 0 or end > self.model.size:
            return codec.ERR_ACCESS, b""
        if end > _DYNAMIC_START and addr < _DYNAMIC_END:
            self.refresh(now)
        data = bytes(self.mem[addr:end])
        for a_item, d_item, count in self.model.indirect:
            if addr < d_item + count and end > d_item:
                data = bytearray(data)
                for k in range(max(addr, d_item), min(end, d_item + count)):
                    target = self._get_raw(a_item + 2 * (k - d_item), 2)
                    if _DYNAMIC_START <= target < _DYNAMIC_END:
                        self.refresh(now)
                    data[k - addr] = self.mem[target] if target < self.model.size else 0
                data = bytes(data)
        return 0, data

    def check_write(self, addr: int, data: bytes) -> int:
        """The error a Write of ``data`` at ``addr`` would get (0 if it is accepted)."""
        end = addr + len(data)
        if not data or end > self.model.size:
            return codec.ERR_ACCESS
        amap = self._amap
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
            if f.eeprom and self.mem[64]:
                return codec.ERR_ACCESS
            first = self.spec.bus_watchdog_firmware
            if f.addr == 98 and (first is None or self.mem[6] < first):
                return codec.ERR_ACCESS  # firmware without the Bus Watchdog
            if f.addr in _GOAL_ADDRS and self.mem[98] == WATCHDOG_TRIPPED:
                return codec.ERR_DATA_RANGE  # refused until the watchdog is cleared
            value = int.from_bytes(data[k - addr:k - addr + f.size], "little", signed=f.signed)
            if f.lo is not None and not f.lo <= value <= f.hi:
                return codec.ERR_DATA_RANGE
            if f.addr == 11 and value not in OPERATING_MODES.get(self.model.name, {value}):
                return codec.ERR_DATA_RANGE
            if f.addr == 116 and self.mem[11] == 3:
                lo, hi = self._get_raw(52, 4), self._get_raw(48, 4)
                if not lo <= value <= hi:
                    return codec.ERR_DATA_LIMIT
            k += f.size
        return 0

    def write(self, addr: int, data: bytes, now: float) -> int:
        """Apply a Write (all-or-nothing); returns the error number (0 = done)."""
        self.hear(now)
        err = self.check_write(addr, data)
        if err:
            return err
        end = addr + len(data)
        torque_before, mode_before = self.mem[64], self.mem[11]
        if addr <= 64 < end and data[64 - addr] == 1 and self.mem[70]:
            data = bytearray(data)
            data[64 - addr] = 0  # a latched hardware error keeps torque off until reboot
        for a_item, d_item, count in self.model.indirect:
            if addr < d_item + count and end > d_item:
                for k in range(max(addr, d_item), min(end, d_item + count)):
                    target = self._get_raw(a_item + 2 * (k - d_item), 2)
                    entry = self._amap[target] if target < self.model.size else None
                    if entry is not None and entry[0].writable and not entry[0].eeprom:
                        self.mem[target] = data[k - addr]
        self.mem[addr:end] = data
        if self.mem[11] != mode_before:
            self._rebase()
            for name in ("Profile Acceleration", "Profile Velocity"):
                self.set(name, 0)
        if self.mem[64] and not torque_before:
            if self.mem[11] == 3:
                self._rebase()
            self.velocity = 0.0
            # The servo holds where it is: Goal Position takes Present Position (no jump).
            if not (addr <= 116 < end):
                self.mem[116:120] = self._present_position().to_bytes(4, "little", signed=True)
        if (self.mem[10] & 0x08) and addr <= 116 < end and not self.mem[64] and not self.mem[70]:
            self.mem[64] = 1  # Drive Mode bit 3: Torque On by Goal Update
            self.velocity = 0.0
        if not self.mem[64]:
            self._traj = None
        elif addr <= 116 < end and self.mem[10] & 0x04 and self.mem[11] in (3, 4, 5):
            self._start_time_profile(now)
        self.refresh(now)
        return 0

    def clear_multi_turn(self, now: float) -> int:
        """Clear instruction: re-base Present Position into one turn; Result Fail if moving."""
        self.refresh(now)
        if self.mem[122]:
            return codec.ERR_RESULT_FAIL
        self._rebase()
        self.refresh(now)
        return 0
