"""Control-table items for driving X-series servos (declared as data). Per-model units (current,
velocity, Bus Watchdog firmware) are fields of ``puppet.servo_models.MODELS``."""

from __future__ import annotations

from puppet.bus.control_table import (GOAL_POSITION, HARDWARE_ERROR_STATUS, OPERATING_MODE,
                                      PRESENT_POSITION, TORQUE_ENABLE, Item)

DRIVE_MODE = Item("Drive Mode", 10, 1, eeprom=True)
CURRENT_LIMIT = Item("Current Limit", 38, 2, eeprom=True)
TEMPERATURE_LIMIT = Item("Temperature Limit", 31, 1, eeprom=True)
MAX_POSITION_LIMIT = Item("Max Position Limit", 48, 4, eeprom=True)
MIN_POSITION_LIMIT = Item("Min Position Limit", 52, 4, eeprom=True)
BUS_WATCHDOG = Item("Bus Watchdog", 98, 1, signed=True)
PROFILE_ACCELERATION = Item("Profile Acceleration", 108, 4)
PROFILE_VELOCITY = Item("Profile Velocity", 112, 4)

STATE_ADDRESS = 122
"""The cycle's one contiguous read, Moving (122) .. Present Temperature (146), 25 bytes:
Moving 122, Moving Status 123, Present PWM 124, Present Current/Load 126, Present Velocity
128, Present Position 132, Velocity/Position Trajectory 136/140, Input Voltage 144,
Present Temperature 146."""
STATE = Item("Moving .. Present Temperature", STATE_ADDRESS, 25)
STATE_OFFSETS = {"moving": (0, 1, False), "moving_status": (1, 1, False),
                 "current": (4, 2, True), "velocity": (6, 4, True),
                 "position": (10, 4, True), "temperature": (24, 1, False)}

POSITION_MODES = {3: "position", 4: "extended position", 5: "current-based position"}
POSITION_MODE = 3
DRIVE_MODE_TIME_PROFILE = 0x04
DRIVE_MODE_TORQUE_ON_BY_GOAL = 0x08
WATCHDOG_UNIT_S = 0.020
WATCHDOG_TRIPPED = -1
MOVING_STATUS_IN_POSITION = 0x01
ACCEL_UNIT_DEG_S2 = 214.577 * 360.0 / 3600.0   # one Profile Acceleration unit, degrees/s^2

__all__ = ["DRIVE_MODE", "CURRENT_LIMIT", "TEMPERATURE_LIMIT", "MAX_POSITION_LIMIT",
           "MIN_POSITION_LIMIT", "BUS_WATCHDOG", "PROFILE_ACCELERATION", "PROFILE_VELOCITY",
           "STATE", "STATE_OFFSETS", "GOAL_POSITION", "HARDWARE_ERROR_STATUS", "OPERATING_MODE",
           "PRESENT_POSITION", "TORQUE_ENABLE"]
