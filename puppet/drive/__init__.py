"""Driving the servos: a take performed on the puppet (``perform``), safely.

- ``items``: the control-table items and per-model units used to drive.
- ``goals``: goal ticks from a take's ticks through two calibrations, interpolated, clamped,
  rate-limited (pure numpy; no bus).
- ``servos``: the bus side: setup before torque, group goal writes, the state read, the stop.
- ``perform``: the performance: setup, slow start, playback loop, health watchdog, stop.
"""

from puppet.drive.errors import DriveError, HealthStop
from puppet.drive.goals import TakeGoals
from puppet.drive.perform import PerformOptions, PerformReport, perform

__all__ = ["DriveError", "HealthStop", "TakeGoals", "PerformOptions", "PerformReport", "perform"]
