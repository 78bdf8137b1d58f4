"""Multi-turn continuity across servo reboots and encoder wraps.

With torque off, an X-series Present Position counts continuously past 0 and 4095 (signed
int32); a reboot or power cycle re-bases it into 0..4095 (plus Homing Offset). An MX on Protocol
1.0 reports 0..4095 and wraps from 4095 to 0 as its shaft turns on. ``TurnUnwrapper`` adds whole
turns (the model's ``ticks_per_turn``) so the reported count stays continuous: on a jump of more
than half a turn to a value inside 0..ticks_per_turn-1, it picks the whole-turn offset that puts
the new value nearest the last good one. A model whose positions do not cover a whole turn (AX,
RX, XL-320: 1024 positions over 300°, the rest a dead zone) is never unwrapped: its reading is
absolute and a jump is the shaft crossing the dead zone (``period`` None).
"""

from __future__ import annotations

from puppet.servo_models import TICKS_PER_TURN


def nearest_turn_offset(raw: int, last: int, period: int = TICKS_PER_TURN) -> int:
    """Whole-turn offset (ticks, a multiple of ``period``) that puts ``raw`` nearest ``last``."""
    return int(round((last - raw) / period)) * period


def unwrap_period(model) -> int | None:
    """The turn (ticks) a ``ServoModel``'s readings are unwrapped by: its ``ticks_per_turn``
    when its positions cover a whole turn, else None (no unwrap)."""
    return model.position_ticks if model.dead_zone_deg == 0 else None


class TurnUnwrapper:
    """Per-servo turn offset. ``offset`` is added to every raw reading; ``last`` is the last
    good continuous value (None before the first reading); ``period``: ticks per turn, or None
    for a servo never unwrapped."""

    __slots__ = ("offset", "last", "period")

    def __init__(self, period: int | None = TICKS_PER_TURN) -> None:
        self.offset = 0
        self.last: int | None = None
        self.period = period

    def peek(self, raw: int) -> tuple[int, int]:
        """Raw Present Position -> (continuous ticks, offset it would use); changes nothing."""
        value = raw + self.offset
        period = self.period
        if (period is not None and self.last is not None and abs(value - self.last) > period // 2
                and 0 <= raw < period):
            offset = nearest_turn_offset(raw, self.last, period)
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
