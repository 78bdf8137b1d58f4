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
"""Encoder counts per output revolution of the X-series and MX models (12-bit absolute encoder).
A model's own resolution is its ``ticks_per_turn`` (AX / RX / XL-320: 1024 positions over 300°,
so 1228.8 per 360°); this constant is the X-series value the multi-turn unwrap and the take's
resampling use."""
HALF_TURN = TICKS_PER_TURN // 2
"""Half a turn of ticks: the largest step a reading may take between two reads and still be
taken the short way round."""

NO_FAST_SYNC_READ = 256
"""Above any Firmware Version (one byte): no firmware of the model has Fast Sync Read."""

PRESENT_LOAD_UNIT_PCT = 0.1
"""Present Load unit, % of the maximum torque, of the models that sense no current
(``current_unit_ma`` None): X-series 126, Protocol 1.0 40, XL-320 41."""

VELOCITY_UNIT_RPM = 0.229
"""Profile Velocity / Present Velocity unit, rev/min, of the X-series and MX(2.0) models."""

REALTIME_TICK_WRAP = 32768
"""Realtime Tick counts milliseconds and wraps to 0 after 32767."""

HARDWARE_ERROR_BITS = {
    0: "input voltage",
    2: "overheating",
    3: "motor encoder",
    4: "electrical shock",
    5: "overload",
}
"""Hardware Error Status bits (Protocol 1.0's status error byte keeps 0, 2 and 5 the same)."""


def describe_hardware_error(bits: int) -> str:
    """Hardware Error Status bits -> 'overheating, overload' ('none' for 0)."""
    names = [name for bit, name in HARDWARE_ERROR_BITS.items() if bits & (1 << bit)]
    unknown = bits & ~sum(1 << bit for bit in HARDWARE_ERROR_BITS)
    if unknown:
        names.append(f"unknown bits 0x{unknown:02x}")
    return ", ".join(names) if names else "none"


PROTOCOL_1 = 1.0
PROTOCOL_2 = 2.0
"""Dynamixel protocol versions, as ``dynamixel_sdk.PacketHandler`` takes them."""


@dataclass(frozen=True)
class Item:
    """One control-table item: name (as the e-manual writes it), address (byte offset), size in
    bytes, and how its bytes encode a number.

    signed: two's complement. direction_bit: sign-magnitude instead (Protocol 1.0 / XL-320
    Present Speed, Present Load, Moving Speed in wheel mode: bits 0..9 the magnitude, bit 10 set
    = clockwise = negative). zero: the raw value that means 0 (MX-64 / MX-106 Current (68):
    2048). eeprom: in the EEPROM area (written only while torque is off).
    """

    name: str
    address: int
    size: int
    signed: bool = False
    eeprom: bool = False
    direction_bit: int | None = None
    zero: int = 0

    def decode(self, data: bytes | bytearray | list[int]) -> int:
        """Little-endian bytes -> int."""
        raw = int.from_bytes(bytes(data[: self.size]), "little", signed=self.signed)
        if self.direction_bit is not None:
            magnitude = raw & ((1 << self.direction_bit) - 1)
            return -magnitude if raw >> self.direction_bit & 1 else magnitude
        return raw - self.zero

    def encode(self, value: int) -> list[int]:
        """int -> little-endian byte list of ``size`` bytes (the inverse of :meth:`decode`)."""
        value = int(value)
        if self.direction_bit is not None:
            value = -value | 1 << self.direction_bit if value < 0 else value
        else:
            value += self.zero
        return list(value.to_bytes(self.size, "little", signed=self.signed and value < 0))


@dataclass(frozen=True)
class ControlItems:
    """Where a model keeps the items the host uses (``Item``; None: the model has no such item).

    Position: ``goal_position``, ``present_position``, ``min_position_limit`` /
    ``max_position_limit`` (Protocol 1.0 and XL-320: CW / CCW Angle Limit). Speed:
    ``moving_speed`` (the speed of a position move: Protocol 1.0 / XL-320 Moving Speed,
    X / MX(2.0) Profile Velocity; 0 = as fast as it can), ``present_speed`` (Present Speed /
    Present Velocity). Load: ``present_load`` (0.1 % of the maximum torque) or
    ``present_current`` (``current_unit_ma`` units), ``current_limit``. ``present_voltage``
    (0.1 V), ``present_temperature`` (deg C), ``moving``, ``registered``, ``torque_enable``,
    ``led``, ``temperature_limit``, ``status_return_level``, ``return_delay_time`` (2 µs),
    ``baud_rate``, ``id``, ``model_number``, ``firmware_version``. Protocol 2.0 only:
    ``hardware_error_status`` (Protocol 1.0 reports errors in every status packet's error byte
    instead), ``operating_mode`` (XL-320: Control Mode, 1 wheel / 2 joint), ``drive_mode``,
    ``bus_watchdog``, ``realtime_tick`` (also MX on Protocol 1.0, address 50). The X layout
    only (X-series, MX(2.0)): ``moving_status`` (b0 in position), ``profile_acceleration``
    (the start profile's; other families start at Moving Speed).
    """

    model_number: Item
    firmware_version: Item
    id: Item
    baud_rate: Item
    return_delay_time: Item
    min_position_limit: Item
    max_position_limit: Item
    temperature_limit: Item
    status_return_level: Item
    torque_enable: Item
    led: Item
    goal_position: Item
    moving_speed: Item
    present_position: Item
    present_speed: Item
    present_voltage: Item
    present_temperature: Item
    registered: Item
    moving: Item
    present_load: Item | None = None
    present_current: Item | None = None
    current_limit: Item | None = None
    hardware_error_status: Item | None = None
    operating_mode: Item | None = None
    drive_mode: Item | None = None
    bus_watchdog: Item | None = None
    realtime_tick: Item | None = None
    moving_status: Item | None = None
    profile_acceleration: Item | None = None


def _x_items(current: bool) -> ControlItems:
    """X-series and MX(2.0) (Protocol 2.0): Present Current at 126 when ``current`` (with
    Current Limit 38), Present Load there otherwise."""
    return ControlItems(
        Item("Model Number", 0, 2, eeprom=True), Item("Firmware Version", 6, 1, eeprom=True),
        Item("ID", 7, 1, eeprom=True), Item("Baud Rate", 8, 1, eeprom=True),
        Item("Return Delay Time", 9, 1, eeprom=True),
        Item("Min Position Limit", 52, 4, eeprom=True),
        Item("Max Position Limit", 48, 4, eeprom=True),
        Item("Temperature Limit", 31, 1, eeprom=True), Item("Status Return Level", 68, 1),
        Item("Torque Enable", 64, 1), Item("LED", 65, 1),
        Item("Goal Position", 116, 4, signed=True), Item("Profile Velocity", 112, 4),
        Item("Present Position", 132, 4, signed=True), Item("Present Velocity", 128, 4, signed=True),
        Item("Present Input Voltage", 144, 2), Item("Present Temperature", 146, 1),
        Item("Registered Instruction", 69, 1), Item("Moving", 122, 1),
        present_load=None if current else Item("Present Load", 126, 2, signed=True),
        present_current=Item("Present Current", 126, 2, signed=True) if current else None,
        current_limit=Item("Current Limit", 38, 2, eeprom=True) if current else None,
        hardware_error_status=Item("Hardware Error Status", 70, 1),
        operating_mode=Item("Operating Mode", 11, 1, eeprom=True),
        drive_mode=Item("Drive Mode", 10, 1, eeprom=True),
        bus_watchdog=Item("Bus Watchdog", 98, 1, signed=True),
        realtime_tick=Item("Realtime Tick", 120, 2),
        moving_status=Item("Moving Status", 123, 1),
        profile_acceleration=Item("Profile Acceleration", 108, 4))


def _p1_items(mx: bool = False, current: bool = False) -> ControlItems:
    """AX / RX / MX on Protocol 1.0 (one table; MX adds Realtime Tick at 50, MX-64 / MX-106
    Current at 68)."""
    return ControlItems(
        Item("Model Number", 0, 2, eeprom=True), Item("Firmware Version", 2, 1, eeprom=True),
        Item("ID", 3, 1, eeprom=True), Item("Baud Rate", 4, 1, eeprom=True),
        Item("Return Delay Time", 5, 1, eeprom=True),
        Item("CW Angle Limit", 6, 2, eeprom=True), Item("CCW Angle Limit", 8, 2, eeprom=True),
        Item("Temperature Limit", 11, 1, eeprom=True),
        Item("Status Return Level", 16, 1, eeprom=True),
        Item("Torque Enable", 24, 1), Item("LED", 25, 1),
        Item("Goal Position", 30, 2), Item("Moving Speed", 32, 2),
        Item("Present Position", 36, 2), Item("Present Speed", 38, 2, direction_bit=10),
        Item("Present Voltage", 42, 1), Item("Present Temperature", 43, 1),
        Item("Registered", 44, 1), Item("Moving", 46, 1),
        present_load=Item("Present Load", 40, 2, direction_bit=10),
        present_current=Item("Current", 68, 2, zero=2048) if current else None,
        realtime_tick=Item("Realtime Tick", 50, 2) if mx else None)


_XL320_ITEMS = ControlItems(
    Item("Model Number", 0, 2, eeprom=True), Item("Firmware Version", 2, 1, eeprom=True),
    Item("ID", 3, 1, eeprom=True), Item("Baud Rate", 4, 1, eeprom=True),
    Item("Return Delay Time", 5, 1, eeprom=True),
    Item("CW Angle Limit", 6, 2, eeprom=True), Item("CCW Angle Limit", 8, 2, eeprom=True),
    Item("Temperature Limit", 12, 1, eeprom=True),
    Item("Status Return Level", 17, 1, eeprom=True),
    Item("Torque Enable", 24, 1), Item("LED", 25, 1),
    Item("Goal Position", 30, 2), Item("Moving Speed", 32, 2),
    Item("Present Position", 37, 2), Item("Present Speed", 39, 2, direction_bit=10),
    Item("Present Voltage", 45, 1), Item("Present Temperature", 46, 1),
    Item("Registered Instruction", 47, 1), Item("Moving", 49, 1),
    present_load=Item("Present Load", 41, 2, direction_bit=10),
    hardware_error_status=Item("Hardware Error Status", 50, 1),
    operating_mode=Item("Control Mode", 11, 1, eeprom=True))

X_ITEMS = _x_items(current=True)
"""The X-series items (current-sensing models)."""

BAUDS_X330 = (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)
BAUDS_X430 = BAUDS_X330 + (4_500_000,)
BAUDS_P1 = (9600, 19200, 57600, 115200, 200_000, 250_000, 400_000, 500_000, 1_000_000)
"""AX / RX Baud Rate (4) values 207, 103, 34, 16, 9, 7, 4, 3, 1 (2 Mbit/s / (value + 1),
nominal rates as the e-manual lists them)."""
BAUDS_MX1 = BAUDS_P1 + (2_250_000, 2_500_000, 3_000_000)
"""MX on Protocol 1.0: the AX / RX rates plus values 250, 251, 252."""
BAUDS_XL320 = (9600, 57600, 115200, 1_000_000)


@dataclass(frozen=True)
class ServoModel:
    """A Dynamixel model as the host sees it: every per-model fact is a field here.

    name:                    e.g. "XL430-W250", "AX-12A", "MX-28(2.0)" (what a rig file writes).
    number:                  Model Number (address 0) the servo reports in a ping.
    fast_sync_read_firmware: first firmware version with Fast Sync Read; NO_FAST_SYNC_READ when
                             the model has none (2XL430, every Protocol 1.0 model, MX(2.0),
                             XL-320).
    current_unit_ma:         mA per unit of ``items.present_current`` (and Current Limit); None
                             when the model senses no current (it reports ``items.present_load``,
                             0.1 % of its maximum torque).
    current_limit:           Current Limit default, in current_unit_ma units (None: no such item;
                             MX-64 / MX-106 on Protocol 1.0 sense current but have no limit).
    temperature_limit_c:     Temperature Limit default, deg C.
    bus_watchdog_firmware:   first firmware version with the Bus Watchdog (98); None when the
                             model has none (such a model may not be driven unless told).
    protocol:                PROTOCOL_1 or PROTOCOL_2: the one protocol its firmware speaks.
    position_ticks:          distinct Present Position values in one turn of the usable range:
                             positions 0..position_ticks-1 (4096, or 1024 on AX / RX / XL-320).
    position_range_deg:      degrees those positions cover: 360, or 300 (AX / RX / XL-320: the
                             other 60° are the dead zone, where the potentiometer reads nothing
                             usable). ``ticks_per_turn`` = position_ticks · 360 / range.
    velocity_unit_rpm:       rev/min per unit of ``items.moving_speed`` / ``items.present_speed``.
    sync_read:               the model answers Sync Read (Protocol 2.0, 0x82).
    bulk_read:               the model answers Bulk Read (0x92; on Protocol 1.0 only MX does).
    baud_rates:              the line speeds (bit/s) its Baud Rate item can select, ascending.
    items:                   where it keeps what the host reads and writes (ControlItems).
    """

    name: str
    number: int
    fast_sync_read_firmware: int
    current_unit_ma: float | None
    current_limit: int | None
    temperature_limit_c: int
    bus_watchdog_firmware: int | None = 38
    protocol: float = PROTOCOL_2
    position_ticks: int = TICKS_PER_TURN
    position_range_deg: float = 360.0
    velocity_unit_rpm: float = VELOCITY_UNIT_RPM
    sync_read: bool = True
    bulk_read: bool = True
    baud_rates: tuple[int, ...] = BAUDS_X430
    items: ControlItems = X_ITEMS

    @property
    def ticks_per_turn(self) -> float:
        """Position ticks per 360° of the output shaft (4096; 1228.8 on AX / RX / XL-320)."""
        n = self.position_ticks * 360.0 / self.position_range_deg
        return int(n) if n.is_integer() else n

    @property
    def max_position(self) -> int:
        """The highest Present / Goal Position of the usable range (4095 or 1023)."""
        return self.position_ticks - 1

    @property
    def dead_zone_deg(self) -> float:
        """Degrees of a turn no position reading covers (60 on AX / RX / XL-320, else 0)."""
        return 360.0 - self.position_range_deg

    @property
    def current_limit_ma(self) -> float | None:
        """The default Current Limit in mA (None: the model has no Current Limit)."""
        if self.current_unit_ma is None or self.current_limit is None:
            return None
        return self.current_limit * self.current_unit_ma

    @property
    def velocity_unit_deg_s(self) -> float:
        """Degrees per second of the servo shaft per velocity unit."""
        return self.velocity_unit_rpm * 360.0 / 60.0


_X330 = dict(fast_sync_read_firmware=46, current_unit_ma=1.0, temperature_limit_c=70,
             baud_rates=BAUDS_X330)
_X430_LOAD = dict(current_unit_ma=None, current_limit=None, items=_x_items(current=False))
_XM = dict(fast_sync_read_firmware=45, current_unit_ma=2.69, temperature_limit_c=80)
_P1 = dict(fast_sync_read_firmware=NO_FAST_SYNC_READ, bus_watchdog_firmware=None,
           protocol=PROTOCOL_1, sync_read=False)
_AX_RX = dict(_P1, current_unit_ma=None, current_limit=None, position_ticks=1024,
              position_range_deg=300.0, velocity_unit_rpm=0.111, bulk_read=False,
              baud_rates=BAUDS_P1, items=_p1_items())
_MX1 = dict(_P1, current_limit=None, temperature_limit_c=80, velocity_unit_rpm=0.114,
            baud_rates=BAUDS_MX1)
_MX2 = dict(fast_sync_read_firmware=NO_FAST_SYNC_READ, temperature_limit_c=80)

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
        # Protocol 1.0.
        ServoModel("AX-12A", 12, temperature_limit_c=70, **_AX_RX),
        ServoModel("AX-12W", 300, temperature_limit_c=70, **_AX_RX),
        ServoModel("AX-18A", 18, temperature_limit_c=75, **_AX_RX),
        ServoModel("RX-24F", 24, temperature_limit_c=80, **_AX_RX),
        ServoModel("RX-28", 28, temperature_limit_c=80, **_AX_RX),
        ServoModel("RX-64", 64, temperature_limit_c=80, **_AX_RX),
        ServoModel("MX-12W", 104, current_unit_ma=None, items=_p1_items(mx=True),
                   **dict(_MX1, velocity_unit_rpm=0.916)),
        ServoModel("MX-28", 29, current_unit_ma=None, items=_p1_items(mx=True), **_MX1),
        ServoModel("MX-64", 310, current_unit_ma=4.5, items=_p1_items(mx=True, current=True),
                   **_MX1),
        ServoModel("MX-106", 320, current_unit_ma=4.5, items=_p1_items(mx=True, current=True),
                   **_MX1),
        # Protocol 2.0, not X-series.
        ServoModel("MX-28(2.0)", 30, current_unit_ma=None, current_limit=None,
                   items=_x_items(current=False), **_MX2),
        ServoModel("MX-64(2.0)", 311, current_unit_ma=3.36, current_limit=1941, **_MX2),
        ServoModel("MX-106(2.0)", 321, current_unit_ma=3.36, current_limit=2047, **_MX2),
        ServoModel("XL-320", 350, NO_FAST_SYNC_READ, None, None, temperature_limit_c=65,
                   bus_watchdog_firmware=None, position_ticks=1024, position_range_deg=300.0,
                   velocity_unit_rpm=0.111, baud_rates=BAUDS_XL320, items=_XL320_ITEMS),
    )
}
"""Every model a rig may name. Sources: the ROBOTIS e-manual control tables
(emanual.robotis.com/docs/en/dxl/<series>/<model>/: x/xm430-w210, x/xh430-w350, x/xm540-w150,
x/xc330-t181, x/xc430-w150, x/xl330-m288, x/xl430-w250; ax/ax-12a, ax/ax-12w, ax/ax-18a;
rx/rx-24f, rx/rx-28, rx/rx-64; mx/mx-12w, mx/mx-28, mx/mx-64, mx/mx-106; mx/mx-28-2,
mx/mx-64-2, mx/mx-106-2; x/xl320), the e-manual's protocol pages (protocol1: BULK_READ is MX
only, no Sync Read; protocol2: Fast Sync Read on X-series firmware 45 / 46, not 2XL), and
dynamixel_sdk 4.1.0 (its model list ``dynamixel_easy_sdk/control_table/dynamixel.model`` and
tables ``mx_28.model``, ``mx_64.model``, ``mx_106.model``, ``xl320.model``) for the numbers.

X330: Present Current and Current Limit in 1.0 mA (XL330 1750, XC330-T 910, XC330-M 2352),
Temperature Limit 70 C; XM430 / XH430-W / XM540: 2.69 mA (XM430 1193, XH430-W 648, XM540 2047;
the 1.34 mA unit belongs to the 24 V XH430-V models, not listed), 80 C; XL430 / 2XL430 / XC430:
Present Load in 0.1 % and no Current Limit, 72 C (XL430) and 80 C (XC430). All X: 4096 ticks
per turn, 0.229 rev/min velocity unit, Bus Watchdog (98) from firmware 38 (e-manual "Bus
Watchdog": firmware v38 and above; X330 firmware starts above it).

Protocol 1.0 (no Bus Watchdog, no Hardware Error Status item: errors come in each status
packet's error byte): AX-12A (12), AX-12W (300), AX-18A (18), RX-24F (24), RX-28 (28), RX-64
(64): Present Position at 36 (2 bytes), 1024 positions over 300° (0.29° per unit) and a 60°
dead zone, Moving Speed at 32 in 0.111 rev/min, Present Load at 40 (0.1 %, bit 10 direction),
Temperature Limit 70 (AX-12A / AX-12W), 75 (AX-18A), 80 (RX), baud 2 Mbit/s / (value + 1) up
to 1 Mbit/s, no Bulk Read. MX-12W (104), MX-28 (29), MX-64 (310), MX-106 (320): same addresses,
4096 positions over 360°, Moving Speed 0.114 rev/min (MX-12W 0.916), Realtime Tick at 50,
Bulk Read, baud values 250..252 for 2.25 / 2.5 / 3 Mbit/s, 80 C; MX-64 / MX-106 sense current
at 68 (4.5 mA per unit, 2048 = 0 A) and have no Current Limit.

Protocol 2.0, not X: MX-28(2.0) (30), MX-64(2.0) (311), MX-106(2.0) (321) use the X-series
addresses (Present Position 132, 4 bytes; Bus Watchdog 98, the same e-manual section as the X
series); MX-28(2.0) reports Present Load, MX-64(2.0) / MX-106(2.0) Present Current in 3.36 mA
(Current Limit 1941 / 2047); no Fast Sync Read (not among the e-manual's supported products).
XL-320 (350): its own table (Present Position 37, 2 bytes, 1024 positions over 300°; Goal
Position 30, Moving Speed 32 in 0.111 rev/min, Present Load 41, Hardware Error Status 50),
65 C, 1 Mbit/s at most, no Bus Watchdog, no Fast Sync Read."""
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
        self._top = np.zeros(k)   # no limits (±inf): no wrap, and no inf − inf computed
        np.add(self.lo, self.hi, out=self._top, where=self._wrap)
        self._top = np.where(self._wrap, self._top / 2.0 + np.pi, 0.0)
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


def protocol_of(servos) -> float:
    """The one protocol of the servos ``servos`` ({id: model name}; 2.0 when empty).

    One bus carries one protocol: a Protocol 1.0 servo ignores Protocol 2.0 packets and the
    other way round, so one port reads one or the other (ROBOTIS documents no adapter that would
    do both). ValueError naming the servos of each protocol when they mix; a model not in the
    table names the table (``model_named``)."""
    by_protocol: dict[float, list[str]] = {}
    for dxl_id, name in servos.items():
        by_protocol.setdefault(model_named(name).protocol, []).append(f"{dxl_id} ({name})")
    if len(by_protocol) > 1:
        parts = "; ".join(f"Protocol {p:.1f}: servos {', '.join(ids)}"
                          for p, ids in sorted(by_protocol.items()))
        raise ValueError(f"protocols mixed on one bus ({parts}): one bus carries one protocol; "
                         "put each protocol's servos on a port of their own, or switch the MX "
                         "firmware's protocol (Dynamixel Wizard)")
    return next(iter(by_protocol), PROTOCOL_2)
