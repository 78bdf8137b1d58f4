"""What driving reads and writes, per model: each servo's own items come from its model's
``ControlItems`` (``puppet.servo_models``; a field name such as "goal_position" names the item
on every model, None where the model has none: Moving Status and Profile Acceleration are the
X layout's only), the values driving writes into them, and the cycle's one contiguous state
read, laid out from each model's items.

Per-model units (current, velocity, Bus Watchdog firmware) are fields of
``puppet.servo_models.MODELS``.
"""

from __future__ import annotations

from dataclasses import dataclass

from puppet.servo_models import ControlItems, Item

POSITION_MODES = {3: "position", 4: "extended position", 5: "current-based position"}
POSITION_MODE = 3
XL320_JOINT_MODE = 2
"""XL-320 Control Mode (11): 1 wheel, 2 joint (its only position mode)."""
DRIVE_MODE_TIME_PROFILE = 0x04
DRIVE_MODE_TORQUE_ON_BY_GOAL = 0x08
WATCHDOG_UNIT_S = 0.020
WATCHDOG_TRIPPED = -1
MOVING_STATUS_IN_POSITION = 0x01
ACCEL_UNIT_DEG_S2 = 214.577 * 360.0 / 3600.0   # one Profile Acceleration unit, degrees/s^2
MOVING_SPEED_MAX = {2: 1023, 4: 32767}
"""Largest speed of a position move by the item's size: Moving Speed (2 bytes: 0..1023; bit 10
is a direction only in wheel mode) or Profile Velocity (4 bytes)."""


def x_layout(items: ControlItems) -> bool:
    """Whether a model keeps the X-series layout (X-series and MX(2.0)), where Moving Status
    and Profile Acceleration live."""
    return items.moving_status is not None


def resolve(items: ControlItems, what: str | Item) -> Item | None:
    """The item ``what`` names on a model with ``items``: a ControlItems field name -> that
    model's item (None: it has none); an Item -> itself."""
    return getattr(items, what) if isinstance(what, str) else what


@dataclass(frozen=True)
class StateLayout:
    """One model's cycle read: ``block`` the contiguous item from Present Position's or Moving's
    address (the lower) to the end of the last state item; ``fields`` {name: (offset, Item)}
    for moving, position (Present Position), velocity (Present Speed / Velocity), current
    (Present Current where the model has a Current Limit to hold it against, else Present
    Load) and temperature; ``moving_status`` its offset (X layout) or None; ``load``: current
    is Present Load (0.1 %)."""

    block: Item
    fields: dict
    moving_status: int | None
    load: bool
    """The X layout's block: Moving (122) .. Present Temperature (146), 25 bytes: Moving 122,
    Moving Status 123, Present PWM 124, Present Current/Load 126, Present Velocity 128, Present
    Position 132, Velocity/Position Trajectory 136/140, Input Voltage 144, Present Temperature
    146. Protocol 1.0: Present Position (36) .. Moving (46), 11 bytes; XL-320: Present Position
    (37) .. Moving (49), 13 bytes."""

    @classmethod
    def of(cls, items: ControlItems) -> "StateLayout":
        current = items.present_current if items.current_limit is not None else None
        load = current is None
        chosen = {"moving": items.moving, "position": items.present_position,
                  "velocity": items.present_speed,
                  "current": items.present_load if load else current,
                  "temperature": items.present_temperature}
        start = min(i.address for i in chosen.values())
        end = max(i.address + i.size for i in chosen.values())
        fields = {name: (i.address - start, i) for name, i in chosen.items()}
        status = items.moving_status.address - start if x_layout(items) else None
        return cls(Item(f"{items.present_position.name} .. state", start, end - start), fields,
                   status, load)

    def decode(self, value: int) -> dict[str, int]:
        """The block's value (GroupRead decodes it little-endian, unsigned) -> {field: int};
        'moving_status' is the X layout's byte, else in position whenever not moving."""
        data = value.to_bytes(self.block.size, "little")
        out = {name: item.decode(data[off: off + item.size]) for name, (off, item) in self.fields.items()}
        out["moving_status"] = (data[self.moving_status] if self.moving_status is not None
                                else 0 if out["moving"] else MOVING_STATUS_IN_POSITION)
        return out


__all__ = ["POSITION_MODES", "POSITION_MODE", "XL320_JOINT_MODE", "DRIVE_MODE_TIME_PROFILE",
           "DRIVE_MODE_TORQUE_ON_BY_GOAL", "WATCHDOG_UNIT_S", "WATCHDOG_TRIPPED",
           "MOVING_STATUS_IN_POSITION", "ACCEL_UNIT_DEG_S2", "MOVING_SPEED_MAX", "StateLayout",
           "resolve", "x_layout"]
