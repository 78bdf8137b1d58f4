"""X-series control tables declared as data: the X330, X430 and X540 models in MODEL_SPECS.

Each ``Field`` is one control-table item: address, size in bytes, access, default, valid range
(inclusive; ``None`` = any value of its size), EEPROM or RAM, signedness. Sources: the ROBOTIS
e-manual tables as summarised in shared/ref/dynamixel.md §3.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hw_sim.errors import UnknownModelError

EEPROM_END = 64  # addresses 0..63 are EEPROM: writable only while Torque Enable is 0
TICKS_PER_TURN = 4096  # encoder counts per output turn (device-side copy of puppet's)
VELOCITY_UNIT_RPM = 0.229  # Profile / Present Velocity unit of every X-series model here
BUS_WATCHDOG_FIRMWARE = 38  # first firmware with the Bus Watchdog (98) on every model here


@dataclass(frozen=True)
class Field:
    """One control-table item. addr/size: bytes; lo/hi: inclusive range of the raw value."""

    name: str
    addr: int
    size: int
    access: str  # "R" or "RW"
    default: int = 0
    lo: int | None = None
    hi: int | None = None
    signed: bool = False

    @property
    def eeprom(self) -> bool:
        return self.addr < EEPROM_END

    @property
    def writable(self) -> bool:
        return self.access == "RW"


@dataclass(frozen=True)
class ServoModel:
    """A servo model: number, firmware, fields, table size, indirect address/data blocks.

    indirect: ``[(first_address_item, first_data_item, count), ...]``; Indirect Address n holds
    (2 bytes) the address that Indirect Data n (1 byte) mirrors.
    baud_rates: Baud Rate (8) index -> bits per second.
    fast_sync_read_firmware: first firmware with Fast Sync Read (NO_FAST_SYNC_READ: none).
    """

    name: str
    number: int
    firmware: int
    fields: tuple[Field, ...]
    size: int
    indirect: tuple[tuple[int, int, int], ...]
    baud_rates: dict[int, int]
    fast_sync_read_firmware: int = 45
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

    def baud_index(self, baud: int) -> int:
        for index, rate in self.baud_rates.items():
            if rate == baud:
                return index
        raise ValueError(f"{self.name}: baud {baud} is not one of {sorted(self.baud_rates.values())}")


_BAUD_X330 = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000}
_BAUD_X430 = {**_BAUD_X330, 7: 4_500_000}


@dataclass(frozen=True)
class Family:
    """What a servo series shares: table size, indirect blocks, top baud index, Shutdown default,
    Velocity Limit range."""

    size: int
    indirect: tuple[tuple[int, int, int], ...]
    baud_max: int
    shutdown: int
    velocity_limit_max: int


FAMILIES = {
    "X330": Family(228, ((168, 208, 20),), 6, 53, 2047),
    "X430": Family(662, ((168, 224, 28), (578, 634, 28)), 7, 52, 1023),
    "X540": Family(662, ((168, 224, 28), (578, 634, 28)), 7, 52, 1023),
}

NO_FAST_SYNC_READ = 256  # above any Firmware Version byte: the model has no Fast Sync Read

_ALL_MODES = (0, 1, 3, 4, 5, 16)
_NO_CURRENT_MODES = (1, 3, 4, 16)


@dataclass(frozen=True)
class ModelSpec:
    """One row of the model table: what differs between models of a family.

    max_voltage / min_voltage: (default, lo, hi) in 0.1 V; current_limit: default and top of
    Current Limit (38) or None when the model has no current sensing (Present Load at 126);
    velocity_limit: Velocity Limit (44) default, 0.229 rpm; gains: Velocity I, Velocity P,
    Position D, Position I, Position P defaults; nominal_voltage: Present Input Voltage, 0.1 V.
    current_unit_ma: mA per unit of Present Current / Current Limit (None: Present Load, 0.1 %
    of the motor's current); stall_current_ma: the most current the motor draws (None: the
    Current Limit's default in mA); bus_watchdog_firmware: first firmware with the Bus Watchdog
    (None: none); ticks_per_turn; velocity_unit_rpm.
    Model numbers are exact (e-manual, SDK model list); units, Current Limit and Temperature
    Limit follow the e-manual tables of every model (see puppet.servo_models.MODELS, which must
    agree: tests/hw_sim/test_hwsim_models.py); voltages and gains follow the e-manual where read
    (XL330-M288, XL430-W250, XC430-W150, XM430-W210/W350, XH430-W350, XM540-W150, XC330-T181/T288)
    and the nearest sibling's otherwise.
    """

    name: str
    number: int
    family: str
    fast_sync_read_firmware: int
    temp_limit: int
    max_voltage: tuple[int, int, int]
    min_voltage: tuple[int, int, int]
    current_limit: int | None
    velocity_limit: int
    modes: tuple[int, ...]
    gains: tuple[int, int, int, int, int]
    nominal_voltage: int
    current_unit_ma: float | None = None
    stall_current_ma: float | None = None
    bus_watchdog_firmware: int | None = BUS_WATCHDOG_FIRMWARE
    ticks_per_turn: int = TICKS_PER_TURN
    velocity_unit_rpm: float = VELOCITY_UNIT_RPM

    @property
    def motor_current_ma(self) -> float:
        """The most current the motor draws, mA (what the simulated current saturates at)."""
        if self.stall_current_ma is not None:
            return self.stall_current_ma
        return self.current_limit * self.current_unit_ma


_V5 = ((70, 31, 70), (35, 31, 70))      # X330 5 V models
_V12_X330 = ((140, 55, 140), (55, 55, 140))
_V12_X430 = ((140, 60, 140), (60, 60, 140))
_V12_XC430 = ((160, 60, 160), (60, 60, 160))
_V12_XM = ((160, 95, 160), (95, 95, 160))
_G_X330 = (1600, 180, 0, 0, 400)
_G_XL430 = (1000, 100, 4000, 0, 640)
_G_XM = (1920, 100, 0, 0, 800)

_MA1 = dict(current_unit_ma=1.0)
_MA269 = dict(current_unit_ma=2.69)
_LOAD = dict(stall_current_ma=1400.0)  # 1.4 A stall at 12 V (e-manual XL430 / XC430)

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
)
"""Every model hw_sim serves (device-side copy: puppet.servo_models names the same models with
the same per-model facts, field by field; tests/hw_sim/test_hwsim_models.py checks)."""


def _x_series(spec: "ModelSpec") -> ServoModel:
    """The full control table of one model from its row of MODEL_SPECS."""
    name, number, family = spec.name, spec.number, FAMILIES[spec.family]
    temp_limit, max_v, min_v = spec.temp_limit, spec.max_voltage, spec.min_voltage
    current_limit, velocity_limit, modes = spec.current_limit, spec.velocity_limit, spec.modes
    shutdown, indirect, size, baud_max = family.shutdown, family.indirect, family.size, family.baud_max
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
        F("Startup Configuration", 60, 1, "RW", 0, 0, 3),
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
        F("Backup Ready", 147, 1, "R", 0),
    ]
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
    return ServoModel(name, number, 52, tuple(fields), size, indirect,
                      _BAUD_X330 if baud_max == 6 else _BAUD_X430,
                      fast_sync_read_firmware=spec.fast_sync_read_firmware, spec=spec)


def _indirect_base(indirect: tuple, addr_item: int) -> int:
    base = 0
    for a, _, count in indirect:
        if a == addr_item:
            return base
        base += count
    return base


MODELS: dict[str, ServoModel] = {spec.name: _x_series(spec) for spec in MODEL_SPECS}

# Nominal supply (0.1 V) and idle temperature (deg C) per model, for Present Input Voltage etc.
NOMINAL_VOLTAGE = {spec.name: spec.nominal_voltage for spec in MODEL_SPECS}
IDLE_TEMPERATURE = 31

# Valid operating modes per model (the range check above is min..max; this is the exact set).
OPERATING_MODES = {spec.name: set(spec.modes) for spec in MODEL_SPECS}


def get_model(name: str) -> ServoModel:
    """The model named ``name`` (e.g. "XL330-M288"); UnknownModelError lists the known ones."""
    try:
        return MODELS[name]
    except KeyError:
        raise UnknownModelError(
            f"unknown servo model {name!r}; known: {', '.join(sorted(MODELS))}") from None
