"""Control tables declared as data: every model hw_sim serves, in MODEL_SPECS.

Each ``Field`` is one control-table item: address, size in bytes, access, default, valid range
(inclusive; ``None`` = any value of its size), EEPROM or RAM, signedness. A ``Family`` is what a
series shares: its protocol, table layout, baud rates and position resolution. Three layouts:

- X-series and MX(2.0), Protocol 2.0: Present Position 132 (4 bytes, signed), EEPROM 0..63.
- AX / RX / MX on Protocol 1.0: Present Position 36 (2 bytes), EEPROM 0..23; AX / RX 1024
  positions over 300° (a 60° dead zone), MX 4096 over 360°; MX adds Realtime Tick (50) and
  Goal Acceleration (73), MX-64 / MX-106 Current (68, 4.5 mA, 2048 = 0 A).
- XL-320, Protocol 2.0 with its own table: Present Position 37 (2 bytes), 1024 over 300°,
  EEPROM 0..23.

Sources: the ROBOTIS e-manual tables (docs/en/dxl/x/*, ax/ax-12a, ax-12w, ax-18a, rx/rx-24f,
rx-28, rx-64, mx/mx-12w, mx-28, mx-64, mx-106, mx-28-2, mx-64-2, mx-106-2, x/xl320) as
summarised in shared/ref/dynamixel.md §2-3, and dynamixel_sdk's ``mx_*.model`` /
``xl320.model``. puppet.servo_models.MODELS names the same models with the same per-model facts
(tests/hw_sim/test_hwsim_models.py checks, item by item).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

from hw_sim.errors import UnknownModelError

EEPROM_END = 64  # X-series: addresses 0..63 are EEPROM, writable only while Torque Enable is 0
TICKS_PER_TURN = 4096  # X-series encoder counts per output turn (device-side copy of puppet's)
VELOCITY_UNIT_RPM = 0.229  # Profile / Present Velocity unit of the X-series and MX(2.0) models
BUS_WATCHDOG_FIRMWARE = 38  # first firmware with the Bus Watchdog (98) on X-series and MX(2.0)
NO_FAST_SYNC_READ = 256  # above any Firmware Version byte: the model has no Fast Sync Read
PROTOCOL_1, PROTOCOL_2 = 1.0, 2.0


@dataclass(frozen=True)
class Field:
    """One control-table item. addr/size: bytes; lo/hi: inclusive range of the raw value;
    eeprom_end: the first RAM address of its table (the item is EEPROM below it)."""

    name: str
    addr: int
    size: int
    access: str  # "R" or "RW"
    default: int = 0
    lo: int | None = None
    hi: int | None = None
    signed: bool = False
    eeprom_end: int = EEPROM_END

    @property
    def eeprom(self) -> bool:
        return self.addr < self.eeprom_end

    @functools.cached_property
    def bounds(self) -> tuple[int, int]:
        """(lo, hi): every raw value ``size`` bytes hold (two's complement when signed)."""
        bits = 8 * self.size
        return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.signed else (0, (1 << bits) - 1)

    @property
    def writable(self) -> bool:
        return self.access == "RW"


@dataclass(frozen=True)
class ServoModel:
    """A servo model: number, firmware, fields, table size, indirect address/data blocks.

    indirect: ``[(first_address_item, first_data_item, count), ...]``; Indirect Address n holds
    (2 bytes) the address that Indirect Data n (1 byte) mirrors.
    baud_rates: Baud Rate index -> bits per second.
    fast_sync_read_firmware: first firmware with Fast Sync Read (NO_FAST_SYNC_READ: none).
    protocol: PROTOCOL_1 or PROTOCOL_2; eeprom_end: first RAM address.
    """

    name: str
    number: int
    firmware: int
    fields: tuple[Field, ...]
    size: int
    indirect: tuple[tuple[int, int, int], ...]
    baud_rates: dict[int, int]
    fast_sync_read_firmware: int = 45
    protocol: float = PROTOCOL_2
    eeprom_end: int = EEPROM_END
    spec: "ModelSpec | None" = field(default=None, compare=False)
    by_name: dict[str, Field] = field(default_factory=dict, compare=False)
    by_addr: dict[int, Field] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        for f in self.fields:
            self.by_name[f.name] = f
            self.by_addr[f.addr] = f

    def field(self, name: str) -> Field:
        try:
            return self.by_name[name]
        except KeyError:
            raise KeyError(f"{self.name}: no control-table item named {name!r}") from None

    def item(self, *names: str) -> Field:
        """The first of ``names`` this table has (e.g. "Present Velocity", "Present Speed")."""
        for name in names:
            if name in self.by_name:
                return self.by_name[name]
        raise KeyError(f"{self.name}: none of the control-table items {names}")

    def baud_index(self, baud: int) -> int:
        for index, rate in self.baud_rates.items():
            if rate == baud:
                return index
        raise ValueError(f"{self.name}: baud {baud} is not one of {sorted(self.baud_rates.values())}")


_BAUD_X330 = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000}
_BAUD_X430 = {**_BAUD_X330, 7: 4_500_000}
# Protocol 1.0: value v -> 2 Mbit/s / (v + 1), the nominal rates the e-manual lists.
_BAUD_P1 = {1: 1_000_000, 3: 500_000, 4: 400_000, 7: 250_000, 9: 200_000, 16: 115200, 34: 57600,
            103: 19200, 207: 9600}
_BAUD_MX1 = {**_BAUD_P1, 250: 2_250_000, 251: 2_500_000, 252: 3_000_000}
_BAUD_XL320 = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000}


@dataclass(frozen=True)
class Family:
    """What a servo series shares. layout: "X", "P1" or "XL320" (which table builder);
    size: table size; indirect: indirect blocks; baud_rates: index -> bit/s; shutdown: Shutdown
    default; velocity_limit_max; protocol; position_ticks / position_range_deg: positions
    0..position_ticks-1 cover that many degrees; sync_read / bulk_read: group reads it answers."""

    layout: str
    size: int
    indirect: tuple[tuple[int, int, int], ...]
    baud_rates: dict[int, int]
    shutdown: int
    velocity_limit_max: int = 1023
    protocol: float = PROTOCOL_2
    position_ticks: int = TICKS_PER_TURN
    position_range_deg: float = 360.0
    sync_read: bool = True
    bulk_read: bool = True


_X_INDIRECT = ((168, 224, 28), (578, 634, 28))
FAMILIES = {
    "X330": Family("X", 228, ((168, 208, 20),), _BAUD_X330, 53, 2047),
    "X430": Family("X", 662, _X_INDIRECT, _BAUD_X430, 52),
    "X540": Family("X", 662, _X_INDIRECT, _BAUD_X430, 52),
    "MX2": Family("X", 662, _X_INDIRECT, _BAUD_X430, 52),
    "AX": Family("P1", 50, (), _BAUD_P1, 36, protocol=PROTOCOL_1, position_ticks=1024,
                 position_range_deg=300.0, sync_read=False, bulk_read=False),
    "MX1": Family("P1", 74, (), _BAUD_MX1, 36, protocol=PROTOCOL_1, sync_read=False),
    "XL320": Family("XL320", 53, (), _BAUD_XL320, 3, position_ticks=1024,
                    position_range_deg=300.0),
}

_ALL_MODES = (0, 1, 3, 4, 5, 16)
_NO_CURRENT_MODES = (1, 3, 4, 16)


@dataclass(frozen=True)
class ModelSpec:
    """One row of the model table: what differs between models of a family.

    max_voltage / min_voltage: (default, lo, hi) in 0.1 V; current_limit: default and top of
    Current Limit (38) or None when the model has none; velocity_limit: Velocity Limit (44)
    default, 0.229 rpm (X layout only); gains: X layout: Velocity I, Velocity P, Position D,
    Position I, Position P defaults; MX on Protocol 1.0: D, I, P (26..28); nominal_voltage:
    Present Input Voltage, 0.1 V. current_unit_ma: mA per unit of Present Current (None:
    Present Load, 0.1 % of the motor's current); stall_current_ma: the most current the motor
    draws (None: the Current Limit's default in mA); bus_watchdog_firmware: first firmware with
    the Bus Watchdog (None: none); velocity_unit_rpm: Moving Speed / Profile Velocity unit;
    max_torque: Protocol 1.0 / XL-320 Max Torque (14 / 15) default.
    Model numbers are exact (e-manual, SDK model list); units, Current Limit and Temperature
    Limit follow the e-manual tables of every model (see puppet.servo_models.MODELS, which must
    agree: tests/hw_sim/test_hwsim_models.py); voltages and gains follow the e-manual where read
    (XL330-M288, XL430-W250, XC430-W150, XM430-W210/W350, XH430-W350, XM540-W150, XC330-T181/T288,
    the Protocol 1.0 models, MX-64(2.0), XL-320) and the nearest sibling's otherwise.
    """

    name: str
    number: int
    family: str
    fast_sync_read_firmware: int
    temp_limit: int
    max_voltage: tuple[int, int, int]
    min_voltage: tuple[int, int, int]
    current_limit: int | None
    velocity_limit: int = 0
    modes: tuple[int, ...] = ()
    gains: tuple[int, ...] = ()
    nominal_voltage: int = 120
    current_unit_ma: float | None = None
    stall_current_ma: float | None = None
    bus_watchdog_firmware: int | None = BUS_WATCHDOG_FIRMWARE
    velocity_unit_rpm: float = VELOCITY_UNIT_RPM
    max_torque: int = 1023

    @property
    def motor_current_ma(self) -> float:
        """The most current the motor draws, mA (what the simulated current saturates at)."""
        if self.stall_current_ma is not None:
            return self.stall_current_ma
        return self.current_limit * self.current_unit_ma

    @property
    def protocol(self) -> float:
        return FAMILIES[self.family].protocol

    @property
    def position_ticks(self) -> int:
        return FAMILIES[self.family].position_ticks

    @property
    def position_range_deg(self) -> float:
        return FAMILIES[self.family].position_range_deg

    @property
    def ticks_per_turn(self) -> float:
        """Position ticks per 360° (4096; 1228.8 when 1024 positions cover 300°)."""
        n = self.position_ticks * 360.0 / self.position_range_deg
        return int(n) if n.is_integer() else n

    @property
    def sync_read(self) -> bool:
        return FAMILIES[self.family].sync_read

    @property
    def bulk_read(self) -> bool:
        return FAMILIES[self.family].bulk_read

    @property
    def baud_rates(self) -> tuple[int, ...]:
        return tuple(sorted(FAMILIES[self.family].baud_rates.values()))


_V5 = ((70, 31, 70), (35, 31, 70))      # X330 5 V models
_V12_X330 = ((140, 55, 140), (55, 55, 140))
_V12_X430 = ((140, 60, 140), (60, 60, 140))
_V12_XC430 = ((160, 60, 160), (60, 60, 160))
_V12_XM = ((160, 95, 160), (95, 95, 160))
_V_AX = ((140, 50, 250), (60, 50, 250))
_V_RX = ((190, 50, 250), (60, 50, 250))
_V_MX = ((160, 50, 250), (60, 50, 250))
_V_XL320 = ((90, 50, 250), (60, 50, 250))
_G_X330 = (1600, 180, 0, 0, 400)
_G_XL430 = (1000, 100, 4000, 0, 640)
_G_XM = (1920, 100, 0, 0, 800)
_G_MX2 = (1920, 100, 0, 0, 850)

_MA1 = dict(current_unit_ma=1.0)
_MA269 = dict(current_unit_ma=2.69)
_LOAD = dict(stall_current_ma=1400.0)  # 1.4 A stall at 12 V (e-manual XL430 / XC430)
_P1 = dict(fast_sync_read_firmware=NO_FAST_SYNC_READ, bus_watchdog_firmware=None,
           current_limit=None)
_AX = dict(_P1, family="AX", velocity_unit_rpm=0.111)
_MX1 = dict(_P1, family="MX1", temp_limit=80, max_voltage=_V_MX[0], min_voltage=_V_MX[1],
            velocity_unit_rpm=0.114, gains=(0, 0, 32), nominal_voltage=120)
_MX2 = dict(family="MX2", fast_sync_read_firmware=NO_FAST_SYNC_READ, temp_limit=80,
            max_voltage=_V12_XM[0], min_voltage=_V12_XM[1], gains=_G_MX2, nominal_voltage=120)

MODEL_SPECS: tuple[ModelSpec, ...] = (
    ModelSpec("XL330-M077", 1190, "X330", 46, 70, *_V5, 1750, 2047, _ALL_MODES, _G_X330, 50, **_MA1),
    ModelSpec("XL330-M288", 1200, "X330", 46, 70, *_V5, 1750, 445, _ALL_MODES, _G_X330, 50, **_MA1),
    ModelSpec("XC330-T181", 1210, "X330", 46, 70, *_V12_X330, 910, 1023, _ALL_MODES, _G_X330, 120,
              **_MA1),
    ModelSpec("XC330-T288", 1220, "X330", 46, 70, *_V12_X330, 910, 620, _ALL_MODES, _G_X330, 120,
              **_MA1),
    ModelSpec("XC330-M181", 1230, "X330", 46, 70, *_V5, 2352, 1023, _ALL_MODES, _G_X330, 50, **_MA1),
    ModelSpec("XC330-M288", 1240, "X330", 46, 70, *_V5, 2352, 620, _ALL_MODES, _G_X330, 50, **_MA1),
    ModelSpec("XL430-W250", 1060, "X430", 45, 72, *_V12_X430, None, 265, _NO_CURRENT_MODES,
              _G_XL430, 115, **_LOAD),
    ModelSpec("2XL430-W250", 1090, "X430", NO_FAST_SYNC_READ, 72, *_V12_X430, None, 265,
              _NO_CURRENT_MODES, _G_XL430, 115, **_LOAD),
    ModelSpec("XC430-W150", 1070, "X430", 45, 80, *_V12_XC430, None, 460, _NO_CURRENT_MODES,
              _G_XL430, 115, **_LOAD),
    ModelSpec("XC430-W240", 1080, "X430", 45, 80, *_V12_XC430, None, 306, _NO_CURRENT_MODES,
              _G_XL430, 115, **_LOAD),
    ModelSpec("XM430-W210", 1030, "X430", 45, 80, *_V12_XM, 1193, 330, _ALL_MODES, _G_XM, 120,
              **_MA269),
    ModelSpec("XM430-W350", 1020, "X430", 45, 80, *_V12_XM, 1193, 200, _ALL_MODES, _G_XM, 120,
              **_MA269),
    ModelSpec("XH430-W210", 1010, "X430", 45, 80, *_V12_XM, 648, 210, _ALL_MODES,
              (1920, 100, 0, 0, 900), 120, **_MA269),
    ModelSpec("XH430-W350", 1000, "X430", 45, 80, *_V12_XM, 648, 280, _ALL_MODES,
              (1920, 100, 0, 0, 900), 120, **_MA269),
    ModelSpec("XM540-W150", 1130, "X540", 45, 80, *_V12_XM, 2047, 230, _ALL_MODES, _G_XM, 120,
              **_MA269),
    ModelSpec("XM540-W270", 1120, "X540", 45, 80, *_V12_XM, 2047, 128, _ALL_MODES, _G_XM, 120,
              **_MA269),
    # Protocol 1.0 (stall currents from the e-manual specifications).
    ModelSpec("AX-12A", 12, temp_limit=70, max_voltage=_V_AX[0], min_voltage=_V_AX[1],
              nominal_voltage=111, stall_current_ma=1500.0, **_AX),
    ModelSpec("AX-12W", 300, temp_limit=70, max_voltage=_V_AX[0], min_voltage=_V_AX[1],
              nominal_voltage=111, stall_current_ma=1500.0, **_AX),
    ModelSpec("AX-18A", 18, temp_limit=75, max_voltage=_V_AX[0], min_voltage=_V_AX[1],
              nominal_voltage=111, stall_current_ma=2200.0, max_torque=983, **_AX),
    ModelSpec("RX-24F", 24, temp_limit=80, max_voltage=_V_RX[0], min_voltage=_V_RX[1],
              nominal_voltage=120, stall_current_ma=2400.0, **_AX),
    ModelSpec("RX-28", 28, temp_limit=80, max_voltage=_V_RX[0], min_voltage=_V_RX[1],
              nominal_voltage=148, stall_current_ma=2400.0, **_AX),
    ModelSpec("RX-64", 64, temp_limit=80, max_voltage=_V_RX[0], min_voltage=_V_RX[1],
              nominal_voltage=148, stall_current_ma=2600.0, **_AX),
    ModelSpec("MX-12W", 104, stall_current_ma=1400.0, **dict(_MX1, velocity_unit_rpm=0.916,
                                                              gains=(8, 0, 8))),
    ModelSpec("MX-28", 29, stall_current_ma=1400.0, **_MX1),
    ModelSpec("MX-64", 310, current_unit_ma=4.5, stall_current_ma=4100.0, **_MX1),
    ModelSpec("MX-106", 320, current_unit_ma=4.5, stall_current_ma=5200.0, **_MX1),
    # Protocol 2.0, not X-series.
    ModelSpec("MX-28(2.0)", 30, current_limit=None, velocity_limit=230, modes=_NO_CURRENT_MODES,
              stall_current_ma=1400.0, **_MX2),
    ModelSpec("MX-64(2.0)", 311, current_limit=1941, velocity_limit=435, modes=_ALL_MODES,
              current_unit_ma=3.36, **_MX2),
    ModelSpec("MX-106(2.0)", 321, current_limit=2047, velocity_limit=210, modes=_ALL_MODES,
              current_unit_ma=3.36, **_MX2),
    ModelSpec("XL-320", 350, "XL320", NO_FAST_SYNC_READ, 65, *_V_XL320, None, modes=(1, 2),
              gains=(0, 0, 32), nominal_voltage=74, stall_current_ma=1100.0,
              bus_watchdog_firmware=None, velocity_unit_rpm=0.111),
)
"""Every model hw_sim serves (device-side copy: puppet.servo_models names the same models with
the same per-model facts, field by field; tests/hw_sim/test_hwsim_models.py checks)."""


def _x_series(spec: "ModelSpec") -> ServoModel:
    """The full control table of one X-layout model (X-series, MX(2.0)) from its row."""
    name, number, family = spec.name, spec.number, FAMILIES[spec.family]
    temp_limit, max_v, min_v = spec.temp_limit, spec.max_voltage, spec.min_voltage
    current_limit, velocity_limit, modes = spec.current_limit, spec.velocity_limit, spec.modes
    shutdown, indirect, size = family.shutdown, family.indirect, family.size
    baud_max = max(family.baud_rates)
    present_126 = "Present Current" if current_limit is not None else "Present Load"
    vi, vp, pd, pi, pp = spec.gains
    F = Field
    fields = [
        F("Model Number", 0, 2, "R", number),
        F("Model Information", 2, 4, "R", 0),
        F("Firmware Version", 6, 1, "R", 52),
        F("ID", 7, 1, "RW", 1, 0, 252),
        F("Baud Rate", 8, 1, "RW", 1, 0, baud_max),
        F("Return Delay Time", 9, 1, "RW", 250, 0, 254),
        F("Drive Mode", 10, 1, "RW", 0, 0, 13),
        F("Operating Mode", 11, 1, "RW", 3, min(modes), max(modes)),
        F("Secondary ID", 12, 1, "RW", 255, 0, 255),
        F("Protocol Type", 13, 1, "RW", 2, 1, 22),
        F("Homing Offset", 20, 4, "RW", 0, -1_044_479, 1_044_479, signed=True),
        F("Moving Threshold", 24, 4, "RW", 10, 0, 1023),
        F("Temperature Limit", 31, 1, "RW", temp_limit, 0, 100),
        F("Max Voltage Limit", 32, 2, "RW", max_v[0], max_v[1], max_v[2]),
        F("Min Voltage Limit", 34, 2, "RW", min_v[0], min_v[1], min_v[2]),
        F("PWM Limit", 36, 2, "RW", 885, 0, 885),
        F("Velocity Limit", 44, 4, "RW", velocity_limit, 0, family.velocity_limit_max),
        F("Max Position Limit", 48, 4, "RW", 4095, 0, 4095),
        F("Min Position Limit", 52, 4, "RW", 0, 0, 4095),
        F("Shutdown", 63, 1, "RW", shutdown, 0, 255),
        F("Torque Enable", 64, 1, "RW", 0, 0, 1),
        F("LED", 65, 1, "RW", 0, 0, 1),
        F("Status Return Level", 68, 1, "RW", 2, 0, 2),
        F("Registered Instruction", 69, 1, "R", 0),
        F("Hardware Error Status", 70, 1, "R", 0),
        F("Velocity I Gain", 76, 2, "RW", vi, 0, 16383),
        F("Velocity P Gain", 78, 2, "RW", vp, 0, 16383),
        F("Position D Gain", 80, 2, "RW", pd, 0, 16383),
        F("Position I Gain", 82, 2, "RW", pi, 0, 16383),
        F("Position P Gain", 84, 2, "RW", pp, 0, 16383),
        F("Feedforward 2nd Gain", 88, 2, "RW", 0, 0, 16383),
        F("Feedforward 1st Gain", 90, 2, "RW", 0, 0, 16383),
        F("Bus Watchdog", 98, 1, "RW", 0, 0, 127, signed=True),  # -1 after a trip
        F("Goal PWM", 100, 2, "RW", 885, -885, 885, signed=True),
        F("Goal Velocity", 104, 4, "RW", 0, -velocity_limit, velocity_limit, signed=True),
        F("Profile Acceleration", 108, 4, "RW", 0, 0, 32767),
        F("Profile Velocity", 112, 4, "RW", 0, 0, 32767),
        F("Goal Position", 116, 4, "RW", 0, -1_048_575, 1_048_575, signed=True),
        F("Realtime Tick", 120, 2, "R", 0),
        F("Moving", 122, 1, "R", 0),
        F("Moving Status", 123, 1, "R", 0),
        F("Present PWM", 124, 2, "R", 0, signed=True),
        F(present_126, 126, 2, "R", 0, signed=True),
        F("Present Velocity", 128, 4, "R", 0, signed=True),
        F("Present Position", 132, 4, "R", 0, signed=True),
        F("Velocity Trajectory", 136, 4, "R", 0, signed=True),
        F("Position Trajectory", 140, 4, "R", 0, signed=True),
        F("Present Input Voltage", 144, 2, "R", 0),
        F("Present Temperature", 146, 1, "R", 0),
    ]
    if spec.family == "MX2":
        fields.append(F("Acceleration Limit", 40, 4, "RW", 32767, 0, 32767))
    else:
        fields.append(F("Startup Configuration", 60, 1, "RW", 0, 0, 3))
        fields.append(F("Backup Ready", 147, 1, "R", 0))
    if current_limit is not None:
        fields.append(F("Current Limit", 38, 2, "RW", current_limit, 0, current_limit))
        fields.append(F("Goal Current", 102, 2, "RW", current_limit, -current_limit,
                        current_limit, signed=True))
    if spec.family == "X330":
        fields.append(F("PWM Slope", 62, 1, "RW", 140, 1, 255))
    for addr_item, data_item, count in indirect:
        for n in range(count):
            fields.append(F(f"Indirect Address {n + 1 + _indirect_base(indirect, addr_item)}",
                            addr_item + 2 * n, 2, "RW", data_item + n, 64, size - 1))
            fields.append(F(f"Indirect Data {n + 1 + _indirect_base(indirect, addr_item)}",
                            data_item + n, 1, "RW", 0, 0, 255))
    fields.sort(key=lambda f: f.addr)
    return ServoModel(name, number, 52, tuple(fields), size, indirect, family.baud_rates,
                      fast_sync_read_firmware=spec.fast_sync_read_firmware, spec=spec)


P1_EEPROM_END = 24  # Protocol 1.0 and XL-320: addresses 0..23 are EEPROM


def _p1_series(spec: "ModelSpec") -> ServoModel:
    """The control table of an AX / RX / MX model on Protocol 1.0."""
    family = FAMILIES[spec.family]
    top = family.position_ticks - 1
    mx = spec.family == "MX1"
    max_v, min_v = spec.max_voltage, spec.min_voltage

    def F(*args, **kw) -> Field:
        return Field(*args, eeprom_end=P1_EEPROM_END, **kw)

    fields = [
        F("Model Number", 0, 2, "R", spec.number),
        F("Firmware Version", 2, 1, "R", 42 if mx else 24),
        F("ID", 3, 1, "RW", 1, 0, 253),
        F("Baud Rate", 4, 1, "RW", 1, 0, 254),
        F("Return Delay Time", 5, 1, "RW", 250, 0, 254),
        F("CW Angle Limit", 6, 2, "RW", 0, 0, top),
        F("CCW Angle Limit", 8, 2, "RW", top, 0, top),
        F("Temperature Limit", 11, 1, "RW", spec.temp_limit, 0, 99),
        F("Min Voltage Limit", 12, 1, "RW", min_v[0], min_v[1], min_v[2]),
        F("Max Voltage Limit", 13, 1, "RW", max_v[0], max_v[1], max_v[2]),
        F("Max Torque", 14, 2, "RW", spec.max_torque, 0, 1023),
        F("Status Return Level", 16, 1, "RW", 2, 0, 2),
        F("Alarm LED", 17, 1, "RW", 36, 0, 127),
        F("Shutdown", 18, 1, "RW", 36, 0, 127),
        F("Torque Enable", 24, 1, "RW", 0, 0, 1),
        F("LED", 25, 1, "RW", 0, 0, 1),
        F("Goal Position", 30, 2, "RW", 0, 0, top),
        F("Moving Speed", 32, 2, "RW", 0, 0, 2047),
        F("Torque Limit", 34, 2, "RW", spec.max_torque, 0, 1023),
        F("Present Position", 36, 2, "R", 0),
        F("Present Speed", 38, 2, "R", 0),
        F("Present Load", 40, 2, "R", 0),
        F("Present Voltage", 42, 1, "R", 0),
        F("Present Temperature", 43, 1, "R", 0),
        F("Registered", 44, 1, "R", 0),
        F("Moving", 46, 1, "R", 0),
        F("Lock", 47, 1, "RW", 0, 0, 1),
        F("Punch", 48, 2, "RW", 0 if mx else 32, 0, 1023),
    ]
    if mx:
        d, i, p = spec.gains
        fields += [F("Multi Turn Offset", 20, 2, "RW", 0, -24576, 24576, signed=True),
                   F("Resolution Divider", 22, 1, "RW", 1, 1, 4),
                   F("D Gain", 26, 1, "RW", d, 0, 254), F("I Gain", 27, 1, "RW", i, 0, 254),
                   F("P Gain", 28, 1, "RW", p, 0, 254),
                   F("Realtime Tick", 50, 2, "R", 0),
                   F("Goal Acceleration", 73, 1, "RW", 0, 0, 254)]
        if spec.current_unit_ma is not None:
            fields += [F("Current", 68, 2, "RW", 2048, 0, 4095),
                       F("Torque Ctrl Mode Enable", 70, 1, "RW", 0, 0, 1),
                       F("Goal Torque", 71, 2, "RW", 0, 0, 2047)]
    else:
        fields += [F("CW Compliance Margin", 26, 1, "RW", 1, 0, 255),
                   F("CCW Compliance Margin", 27, 1, "RW", 1, 0, 255),
                   F("CW Compliance Slope", 28, 1, "RW", 32, 0, 254),
                   F("CCW Compliance Slope", 29, 1, "RW", 32, 0, 254)]
    fields.sort(key=lambda f: f.addr)
    return ServoModel(spec.name, spec.number, fields[1].default, tuple(fields), family.size, (),
                      family.baud_rates, fast_sync_read_firmware=spec.fast_sync_read_firmware,
                      protocol=PROTOCOL_1, eeprom_end=P1_EEPROM_END, spec=spec)


def _xl320(spec: "ModelSpec") -> ServoModel:
    """The XL-320's own Protocol 2.0 table (Present Position at 37, 2 bytes)."""
    family = FAMILIES[spec.family]
    max_v, min_v = spec.max_voltage, spec.min_voltage
    d, i, p = spec.gains

    def F(*args, **kw) -> Field:
        return Field(*args, eeprom_end=P1_EEPROM_END, **kw)

    fields = (
        F("Model Number", 0, 2, "R", spec.number),
        F("Firmware Version", 2, 1, "R", 30),
        F("ID", 3, 1, "RW", 1, 0, 252),
        F("Baud Rate", 4, 1, "RW", 3, 0, 3),
        F("Return Delay Time", 5, 1, "RW", 250, 0, 254),
        F("CW Angle Limit", 6, 2, "RW", 0, 0, 1023),
        F("CCW Angle Limit", 8, 2, "RW", 1023, 0, 1023),
        F("Control Mode", 11, 1, "RW", 2, 1, 2),
        F("Temperature Limit", 12, 1, "RW", spec.temp_limit, 0, 150),
        F("Min Voltage Limit", 13, 1, "RW", min_v[0], min_v[1], min_v[2]),
        F("Max Voltage Limit", 14, 1, "RW", max_v[0], max_v[1], max_v[2]),
        F("Max Torque", 15, 2, "RW", 1023, 0, 1023),
        F("Status Return Level", 17, 1, "RW", 2, 0, 2),
        F("Shutdown", 18, 1, "RW", family.shutdown, 0, 7),
        F("Torque Enable", 24, 1, "RW", 0, 0, 1),
        F("LED", 25, 1, "RW", 0, 0, 7),
        F("D Gain", 27, 1, "RW", d, 0, 254),
        F("I Gain", 28, 1, "RW", i, 0, 254),
        F("P Gain", 29, 1, "RW", p, 0, 254),
        F("Goal Position", 30, 2, "RW", 0, 0, 1023),
        F("Moving Speed", 32, 2, "RW", 0, 0, 2047),
        F("Torque Limit", 35, 2, "RW", 1023, 0, 1023),
        F("Present Position", 37, 2, "R", 0),
        F("Present Speed", 39, 2, "R", 0),
        F("Present Load", 41, 2, "R", 0),
        F("Present Voltage", 45, 1, "R", 0),
        F("Present Temperature", 46, 1, "R", 0),
        F("Registered Instruction", 47, 1, "R", 0),
        F("Moving", 49, 1, "R", 0),
        F("Hardware Error Status", 50, 1, "R", 0),
        F("Punch", 51, 2, "RW", 32, 0, 1023),
    )
    return ServoModel(spec.name, spec.number, 30, fields, family.size, (), family.baud_rates,
                      fast_sync_read_firmware=spec.fast_sync_read_firmware,
                      eeprom_end=P1_EEPROM_END, spec=spec)


def _indirect_base(indirect: tuple, addr_item: int) -> int:
    base = 0
    for a, _, count in indirect:
        if a == addr_item:
            return base
        base += count
    return base


_BUILDERS = {"X": _x_series, "P1": _p1_series, "XL320": _xl320}
MODELS: dict[str, ServoModel] = {spec.name: _BUILDERS[FAMILIES[spec.family].layout](spec)
                                 for spec in MODEL_SPECS}

# Nominal supply (0.1 V) and idle temperature (deg C) per model, for Present Input Voltage etc.
NOMINAL_VOLTAGE = {spec.name: spec.nominal_voltage for spec in MODEL_SPECS}
IDLE_TEMPERATURE = 31

# Valid operating modes per model (the range check above is min..max; this is the exact set).
OPERATING_MODES = {spec.name: set(spec.modes) for spec in MODEL_SPECS}


def to_shaft(spec: ModelSpec, ticks: float) -> float:
    """A model's own position ticks -> shaft counts (4096 per turn, the motion sources' unit),
    the middles matched: 2048 -> 2048 on 4096-tick models, 512 -> 2048 on 300° models."""
    return TICKS_PER_TURN / 2 + (ticks - spec.position_ticks // 2) * TICKS_PER_TURN / spec.ticks_per_turn


def from_shaft(spec: ModelSpec, shaft: float) -> float:
    """Shaft counts -> the model's own position ticks (the inverse of :func:`to_shaft`)."""
    return spec.position_ticks // 2 + (shaft - TICKS_PER_TURN / 2) * spec.ticks_per_turn / TICKS_PER_TURN


def get_model(name: str) -> ServoModel:
    """The model named ``name`` (e.g. "XL330-M288"); UnknownModelError lists the known ones."""
    try:
        return MODELS[name]
    except KeyError:
        raise UnknownModelError(
            f"unknown servo model {name!r}; known: {', '.join(sorted(MODELS))}") from None
