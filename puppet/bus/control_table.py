"""The X-series control-table items and servo models this bus uses, declared as data.

Addresses and sizes are Protocol 2.0, shared by every model of ``puppet.servo_models.MODELS``
(X330, X430 and X540 series; ROBOTIS e-manual). Nothing else in ``puppet.bus`` writes a bare
address.
"""

from __future__ import annotations

from dataclasses import dataclass

# The servo models and ticks per turn are one table shared with the rig (puppet.servo_models);
# re-exported here so the bus reads every servo fact from this module.
from puppet.servo_models import (MODELS, MODELS_BY_NUMBER, TICKS_PER_TURN,  # noqa: F401
                                 ServoModel, model_named)


@dataclass(frozen=True)
class Item:
    """One control-table item: name, address (byte offset), size in bytes, signedness."""

    name: str
    address: int
    size: int
    signed: bool = False
    eeprom: bool = False

    def decode(self, data: bytes | bytearray | list[int]) -> int:
        """Little-endian bytes -> int (two's complement when ``signed``)."""
        return int.from_bytes(bytes(data[: self.size]), "little", signed=self.signed)

    def encode(self, value: int) -> list[int]:
        """int -> little-endian byte list of ``size`` bytes."""
        return list(int(value).to_bytes(self.size, "little", signed=self.signed and value < 0))


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
