"""Directions in the character's own words: left, up, forward (glTF: +Y up, +Z forward).

A character in glTF faces +Z with +Y up, so its left hand is on +X. ``describe`` turns a model
space direction into words ("to the character's left", "up and forward"); ``bone_axes`` says
where a bone's local x, y, z point at rest and which way a positive turn about each moves the
bone's tip, which is what a builder needs to pick a servo's ``axis`` and ``sign``.
"""

from __future__ import annotations

import numpy as np

#: (model-space unit vector, words) for the six directions, glTF convention.
DIRECTIONS = (
    ((1.0, 0.0, 0.0), "to the character's left"),
    ((-1.0, 0.0, 0.0), "to the character's right"),
    ((0.0, 1.0, 0.0), "up"),
    ((0.0, -1.0, 0.0), "down"),
    ((0.0, 0.0, 1.0), "forward"),
    ((0.0, 0.0, -1.0), "backward"),
)
#: A component below this (cos 67.5°) is not worth naming next to a larger one.
MINOR = 0.38
#: |axis × tip direction| below this: turning about the axis only twists the bone.
TWIST = 0.3


def describe(vector) -> str:
    """Words for a direction (3,) in model space: its one or two main components, larger first."""
    v = np.asarray(vector, np.float64)
    norm = float(np.linalg.norm(v))
    if norm < 1e-12:
        return "nowhere (zero length)"
    v = v / norm
    parts = sorted(((float(np.dot(v, d)), words) for d, words in DIRECTIONS), reverse=True)
    main = [words for dot, words in parts[:2] if dot >= MINOR]
    if len(main) == 2:
        second = main[1].replace("to the character's ", "")
        return f"{main[0]} and {second}"
    return main[0]


def bone_axes(frame: np.ndarray, head, tail) -> tuple[str, str]:
    """Two comment lines for a bone: where its rest axes point, and what positive turns do.

    frame: (3, 3) rest frame, columns local x, y, z in model space; head, tail: (3,) rest pivot
    and tip. Returns ("x: …, y: …, z: …", "turning +x swings the tip …, …").
    """
    frame = np.asarray(frame, np.float64)
    tip = np.asarray(tail, np.float64) - np.asarray(head, np.float64)
    length = float(np.linalg.norm(tip))
    tip = tip / length if length > 1e-12 else frame[:, 1]
    where = []
    for k, name in enumerate("xyz"):
        text = f"{name}: {describe(frame[:, k])}"
        if float(frame[:, k] @ tip) > 0.9:
            text += " along the bone"
        where.append(text)
    turns = []
    for k, name in enumerate("xyz"):
        motion = np.cross(frame[:, k], tip)
        if np.linalg.norm(motion) < TWIST:
            turns.append(f"+{name} twists it")
        else:
            turns.append(f"+{name} swings the tip {describe(motion)}")
    return ", ".join(where), "turning " + ", ".join(turns)


def turn_words(frame: np.ndarray, head, tail, axis) -> str:
    """What a positive turn about ``axis`` (3,) in the bone's rest frame does, in words."""
    frame = np.asarray(frame, np.float64)
    tip = np.asarray(tail, np.float64) - np.asarray(head, np.float64)
    length = float(np.linalg.norm(tip))
    tip = tip / length if length > 1e-12 else frame[:, 1]
    motion = np.cross(frame @ np.asarray(axis, np.float64), tip)
    if np.linalg.norm(motion) < TWIST:
        return "twist it about the bone (right-handed about its axis)"
    return f"swing its tip {describe(motion)}"
