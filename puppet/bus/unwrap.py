"""Multi-turn continuity across servo reboots.

With torque off, Present Position counts continuously past 0 and 4095 (signed int32). A reboot
or power cycle re-bases it into 0..4095 (plus Homing Offset). ``TurnUnwrapper`` adds whole turns
so the reported count stays continuous: on a jump of more than half a turn to a value inside
0..4095, it picks the whole-turn offset that puts the new value nearest the last good one.
"""

from __future__ import annotations

from puppet.servo_models import HALF_TURN, TICKS_PER_TURN


def nearest_turn_offset(raw: int, last: int) -> int:
    """Whole-turn offset (ticks, a multiple of 4096) that puts ``raw`` nearest ``last``."""
    return int(round((last - raw) / TICKS_PER_TURN)) * TICKS_PER_TURN


class TurnUnwrapper:
    """Per-servo turn offset. ``offset`` is added to every raw reading; ``last`` is the last
    good continuous value (None before the first reading)."""

    __slots__ = ("offset", "last")

    def __init__(self) -> None:
        self.offset = 0
        self.last: int | None = None

    def peek(self, raw: int) -> tuple[int, int]:
        """Raw Present Position -> (continuous ticks, offset it would use); changes nothing."""
        value = raw + self.offset
        if self.last is not None and abs(value - self.last) > HALF_TURN and 0 <= raw < TICKS_PER_TURN:
            offset = nearest_turn_offset(raw, self.last)
            return raw + offset, offset
        return value, self.offset

    def accept(self, raw: int) -> tuple[int, bool]:
        """Take a good raw reading -> (continuous ticks, True when it re-based the turn count)."""
        value, offset = self.peek(raw)
        rebased = offset != self.offset
        self.offset = offset
        self.last = value
        return value, rebased

    def to_raw(self, ticks: int) -> int:
        """Continuous ticks -> the servo's own frame (for goal positions)."""
        return ticks - self.offset
