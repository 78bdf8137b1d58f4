"""X-series control tables declared as data: XL330-M288, XL430-W250, XM430-W350.

Each ``Field`` is one control-table item: address, size in bytes, access, default, valid range
(inclusive; ``None`` = any value of its size), EEPROM or RAM, signedness. Sources: the ROBOTIS
e-manual tables as summarised in shared/ref/dynamixel.md §3.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hw_sim.errors import UnknownModelError

EEPROM_END = 64  # addresses 0..63 are EEPROM: writable only while Torque Enable is 0


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
    """

    name: str
    number: int
    firmware: int
    fields: tuple[Field, ...]
    size: int
    indirect: tuple[tuple[int, int, int], ...]
    baud_rates: dict[int, int]
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


def _x_series(name: str, number: int, *, temp_limit: int, max_v: tuple, min_v: tuple,
              current_limit: int | None, velocity_limit: int, modes: tuple, shutdown: int,
              gains: tuple, present_126: str, indirect: tuple, size: int,
              baud_max: int) -> ServoModel:
    vi, vp, pd, pi, pp = gains
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
        F("Velocity Limit", 44, 4, "RW", velocity_limit, 0, 2047 if number == 1200 else 1023),
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
    if number == 1200:
        fields.append(F("PWM Slope", 62, 1, "RW", 140, 1, 255))
    for addr_item, data_item, count in indirect:
        for n in range(count):
            fields.append(F(f"Indirect Address {n + 1 + _indirect_base(indirect, addr_item)}",
                            addr_item + 2 * n, 2, "RW", data_item + n, 64, size - 1))
            fields.append(F(f"Indirect Data {n + 1 + _indirect_base(indirect, addr_item)}",
                            data_item + n, 1, "RW", 0, 0, 255))
    fields.sort(key=lambda f: f.addr)
    return ServoModel(name, number, 52, tuple(fields), size, indirect,
                      _BAUD_X330 if baud_max == 6 else _BAUD_X430)


def _indirect_base(indirect: tuple, addr_item: int) -> int:
    base = 0
    for a, _, count in indirect:
        if a == addr_item:
            return base
        base += count
    return base


MODELS: dict[str, ServoModel] = {
    "XL330-M288": _x_series(
        "XL330-M288", 1200, temp_limit=70, max_v=(70, 31, 70), min_v=(35, 31, 70),
        current_limit=1750, velocity_limit=445, modes=(0, 1, 3, 4, 5, 16), shutdown=53,
        gains=(1600, 180, 0, 0, 400), present_126="Present Current",
        indirect=((168, 208, 20),), size=228, baud_max=6),
    "XL430-W250": _x_series(
        "XL430-W250", 1060, temp_limit=72, max_v=(140, 60, 140), min_v=(60, 60, 140),
        current_limit=None, velocity_limit=265, modes=(1, 3, 4, 16), shutdown=52,
        gains=(1000, 100, 4000, 0, 640), present_126="Present Load",
        indirect=((168, 224, 28), (578, 634, 28)), size=662, baud_max=7),
    "XM430-W350": _x_series(
        "XM430-W350", 1020, temp_limit=80, max_v=(160, 95, 160), min_v=(95, 95, 160),
        current_limit=1193, velocity_limit=200, modes=(0, 1, 3, 4, 5, 16), shutdown=52,
        gains=(1920, 100, 0, 0, 800), present_126="Present Current",
        indirect=((168, 224, 28), (578, 634, 28)), size=662, baud_max=7),
}

# Nominal supply (0.1 V) and idle temperature (deg C) per model, for Present Input Voltage etc.
NOMINAL_VOLTAGE = {"XL330-M288": 50, "XL430-W250": 115, "XM430-W350": 120}
IDLE_TEMPERATURE = 31

# Actuation model per model: Present Current unit (mA per unit; XL430 reports Present Load in
# 0.1 % of its stall current instead), the current the motor can deliver (mA; the Current Limit
# where the model has one), and the first firmware with the Bus Watchdog.
CURRENT_UNIT_MA = {"XL330-M288": 1.0, "XL430-W250": None, "XM430-W350": 2.69}
STALL_CURRENT_MA = {"XL330-M288": 1750.0, "XL430-W250": 1400.0, "XM430-W350": 3209.0}
BUS_WATCHDOG_FIRMWARE = 38

# Valid operating modes per model (the range check above is min..max; this is the exact set).
OPERATING_MODES = {"XL330-M288": {0, 1, 3, 4, 5, 16}, "XL430-W250": {1, 3, 4, 16},
                   "XM430-W350": {0, 1, 3, 4, 5, 16}}


def get_model(name: str) -> ServoModel:
    """The model named ``name`` (e.g. "XL330-M288"); UnknownModelError lists the known ones."""
    try:
        return MODELS[name]
    except KeyError:
        raise UnknownModelError(
            f"unknown servo model {name!r}; known: {', '.join(sorted(MODELS))}") from None
