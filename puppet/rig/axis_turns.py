"""Which turns ``puppet rig axes`` shows: each servo's joint about its axis, and optionally every
joint without a servo about its x, y and z."""

from __future__ import annotations

import numpy as np

from puppet.rig.rig import Rig

AXIS_NAMES = {(1, 0, 0): "x", (0, 1, 0): "y", (0, 0, 1): "z",
              (-1, 0, 0): "-x", (0, -1, 0): "-y", (0, 0, -1): "-z"}


def axis_name(axis) -> str:
    """'x', '-y', ... for a unit axis (3,) in a bone's rest frame, else its numbers."""
    key = tuple(int(round(c)) for c in axis)
    if key in AXIS_NAMES and np.allclose(axis, key, atol=1e-9):
        return AXIS_NAMES[key]
    return "[" + ", ".join(f"{c:.3g}" for c in axis) + "]"


def axis_turns(rig: Rig, every_joint: bool = False) -> list[tuple]:
    """[(label, bone, axis (3,) in model space, pivot (3,), (positive words, negative words))],
    servos in map order, then (with ``every_joint``) each bone that no servo senses, about its
    rest x, y and z. The words are the ones ``rig init`` and ``calibrate --guided`` use
    (``puppet.rig.directions.turn_words``), for a turn about the axis and against it."""
    from puppet.rig.directions import turn_words

    sk = rig.skeleton

    def words(bone: int, local_axis) -> tuple[str, str]:
        local_axis = np.asarray(local_axis, np.float64)
        return tuple(turn_words(sk.frames[bone], sk.heads[bone], sk.tails[bone], side * local_axis)
                     for side in (1.0, -1.0))

    turns = []
    for servo in rig.servo_map.servos:
        bone = sk.index(servo.joint)
        turns.append((f"servo {servo.id}: {servo.joint} about {axis_name(servo.axis)}", bone,
                      sk.frames[bone] @ servo.axis, sk.heads[bone], words(bone, servo.axis)))
    if every_joint:
        servoed = {servo.joint for servo in rig.servo_map.servos}
        for bone, name in enumerate(sk.names):
            if name in servoed:
                continue
            for k, axis in enumerate("xyz"):
                turns.append((f"{name} about {axis} (no servo)", bone, sk.frames[bone][:, k], sk.heads[bone],
                              words(bone, np.eye(3)[k])))
    return turns
