"""The Dynamixel servo models puppet knows, and the encoder's counts per turn: one table, as data.

What a rig may name, what the bus can read and check, and (through hw_sim's own device-side
copy, kept equal by ``tests/hw_sim/test_hwsim_models.py``) what the simulator can serve all
come from :data:`MODELS`. Every model here is a Protocol 2.0 X-series servo with Present
Position at address 132 (4 bytes, signed); their tables differ in items puppet does not read.

This module imports nothing: the rig, the bus, the take and hw_sim's agreement test all read it.
Model numbers: ROBOTIS e-manual and the SDK's ``dynamixel_easy_sdk/control_table/dynamixel.model``.
"""

from __future__ import annotations

from dataclasses import dataclass

TICKS_PER_TURN = 4096
"""Encoder counts per output revolution (12-bit absolute encoder) on every model below."""

NO_FAST_SYNC_READ = 256
"""Above any Firmware Version (one byte): no firmware of the model has Fast Sync Read."""


@dataclass(frozen=True)
class ServoModel:
    """A Dynamixel model as the host sees it.

    name:                    e.g. "XL430-W250" (what a rig file writes).
    number:                  Model Number (address 0) the servo reports in a ping.
    fast_sync_read_firmware: first firmware version with Fast Sync Read; NO_FAST_SYNC_READ when
                             the model has none (the dual-axis 2XL430).
    """

    name: str
    number: int
    fast_sync_read_firmware: int


MODELS: dict[str, ServoModel] = {
    m.name: m
    for m in (
        ServoModel("XL330-M077", 1190, 46),
        ServoModel("XL330-M288", 1200, 46),
        ServoModel("XC330-T181", 1210, 46),
        ServoModel("XC330-T288", 1220, 46),
        ServoModel("XC330-M181", 1230, 46),
        ServoModel("XC330-M288", 1240, 46),
        ServoModel("XL430-W250", 1060, 45),
        ServoModel("2XL430-W250", 1090, NO_FAST_SYNC_READ),
        ServoModel("XC430-W150", 1070, 45),
        ServoModel("XC430-W240", 1080, 45),
        ServoModel("XM430-W210", 1030, 45),
        ServoModel("XM430-W350", 1020, 45),
        ServoModel("XH430-W210", 1010, 45),
        ServoModel("XH430-W350", 1000, 45),
        ServoModel("XM540-W150", 1130, 45),
        ServoModel("XM540-W270", 1120, 45),
    )
}
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
