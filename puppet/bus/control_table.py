"""The X-series control-table items and servo models this bus uses, declared as data.

The constants below are the X-series addresses (Protocol 2.0; X330, X430, X540 and MX(2.0)):
every model's own addresses, Protocol 1.0 and XL-320 included, are
``puppet.servo_models.MODELS[name].items`` (``Item`` is defined there). Nothing else in
``puppet.bus`` writes a bare address.
"""

from __future__ import annotations

# The servo models and ticks per turn are one table shared with the rig (puppet.servo_models);
# re-exported here so the bus reads every servo fact from this module.
from puppet.servo_models import (MODELS, MODELS_BY_NUMBER, TICKS_PER_TURN,  # noqa: F401
                                 Item, ServoModel, model_named)

MODEL_NUMBER = Item("Model Number", 0, 2, eeprom=True)
FIRMWARE_VERSION = Item("Firmware Version", 6, 1, eeprom=True)
RETURN_DELAY_TIME = Item("Return Delay Time", 9, 1, eeprom=True)
OPERATING_MODE = Item("Operating Mode", 11, 1, eeprom=True)
TORQUE_ENABLE = Item("Torque Enable", 64, 1)
STATUS_RETURN_LEVEL = Item("Status Return Level", 68, 1)
HARDWARE_ERROR_STATUS = Item("Hardware Error Status", 70, 1)
GOAL_POSITION = Item("Goal Position", 116, 4, signed=True)
REALTIME_TICK = Item("Realtime Tick", 120, 2)
PRESENT_POSITION = Item("Present Position", 132, 4, signed=True)

REALTIME_TICK_WRAP = 32768
"""Realtime Tick counts milliseconds and wraps to 0 after 32767."""

ALERT_BIT = 0x80
"""Bit 7 of a status packet's error byte: a hardware error is latched."""
STATUS_ERRORS = {
    0x01: "result fail",
    0x02: "instruction error",
    0x03: "CRC error",
    0x04: "data range error",
    0x05: "data length error",
    0x06: "data limit error",
    0x07: "access error",
}
HARDWARE_ERROR_BITS = {
    0: "input voltage",
    2: "overheating",
    3: "motor encoder",
    4: "electrical shock",
    5: "overload",
}


def describe_hardware_error(bits: int) -> str:
    """Hardware Error Status bits -> 'overheating, overload' ('none' for 0)."""
    names = [name for bit, name in HARDWARE_ERROR_BITS.items() if bits & (1 << bit)]
    unknown = bits & ~sum(1 << bit for bit in HARDWARE_ERROR_BITS)
    if unknown:
        names.append(f"unknown bits 0x{unknown:02x}")
    return ", ".join(names) if names else "none"


def describe_status_error(error: int) -> str:
    """A status packet's error byte -> text ('alert' when bit 7 is set)."""
    parts = []
    if error & ALERT_BIT:
        parts.append("alert (hardware error latched)")
    number = error & 0x7F
    if number:
        parts.append(STATUS_ERRORS.get(number, f"error number {number}"))
    return ", ".join(parts) if parts else "none"
