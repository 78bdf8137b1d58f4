"""Typed errors of driving the servos."""

from __future__ import annotations

from puppet.errors import PuppetError


class DriveError(PuppetError):
    """A performance refused or stopped: the message names the servo, item or file at fault.

    report: the PerformReport so far (torque read back after the stop), when there is one.
    """

    def __init__(self, message: str, report=None) -> None:
        super().__init__(message)
        self.report = report


class HealthStop(DriveError):
    """The health watchdog stopped a performance: servo id, what was read, the limit."""

    def __init__(self, dxl_id: int, reading: str) -> None:
        super().__init__(f"servo {dxl_id}: {reading}; performance stopped, torque off")
        self.dxl_id = dxl_id
        self.reading = reading
