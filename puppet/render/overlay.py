"""Skeleton overlay data: bones as segments colored by their state.

A bone is a rest-pose segment (head, tail) that moves with the handle of the same index
(skeleton bones are the first handles of the FAST model). States follow the solver's
constraint kinds: sensed (full transform from the servos), relative (sensed joint under a free
parent), free (solved), fault (its servo at fault this reading: not answering, an error, out of
its limits, ...: holding its last good angle; the fault log names the condition). A servo whose
value is held only because its reply came late (``late_reply``, a busy host: not a fault,
``Reading.late``) leaves its bone in its own colour: one late reply is not worth a flash of red.
"""

import numpy as np

from puppet.render.errors import RenderInputError

#: Linear-light RGB of each bone state, and of bones drawn without a state.
BONE_STATE_COLORS = {
    "sensed": (0.15, 0.85, 0.3),
    "relative": (0.2, 0.6, 1.0),
    "free": (0.75, 0.75, 0.75),
    "fault": (1.0, 0.15, 0.1),
    None: (1.0, 0.85, 0.2),
}
#: What each bone state means to a puppeteer (the live view's legend).
BONE_STATE_WORDS = {
    "sensed": "follows its servo",
    "relative": "follows its servo, under a free parent",
    "free": "no servo: solved from the others (and pins)",
    "fault": "servo at fault (the fault log says why): holds its last angle",
}

#: Diamond outline of a bone, as a triangle strip in (along, across) coordinates.
BONE_CORNERS = np.array([[0.0, 0.0], [0.2, -1.0], [0.2, 1.0], [1.0, 0.0]], dtype=np.float32)


def rest_segments(bones) -> np.ndarray:
    """Rest segments (b, 2, 4) float32 homogeneous [x y z 1] of heads and tails.

    bones: (b, 2, 3) array-like of rest heads and tails, or an object with `heads` and `tails`
    (b, 3) arrays (e.g. puppet.rig's Skeleton).
    """
    if hasattr(bones, "heads") and hasattr(bones, "tails"):
        bones = np.stack([np.asarray(bones.heads), np.asarray(bones.tails)], axis=1)
    segments = np.asarray(bones, dtype=np.float32)
    if segments.ndim != 3 or segments.shape[1:] != (2, 3):
        raise RenderInputError(f"bones: expected (b, 2, 3) rest heads and tails, got {segments.shape}")
    if not np.all(np.isfinite(segments)):
        raise RenderInputError("bones: non-finite head or tail")
    out = np.ones(segments.shape[:2] + (4,), dtype=np.float32)
    out[..., :3] = segments
    return out


def state_color(state, bone: int) -> tuple[float, float, float]:
    """Color of one bone state: a name, an Enum whose value is a name, or None."""
    key = getattr(state, "value", state)
    if isinstance(key, str):
        key = key.lower()
    try:
        return BONE_STATE_COLORS[key]
    except (KeyError, TypeError) as err:
        names = ", ".join(k for k in BONE_STATE_COLORS if k)
        raise RenderInputError(f"bone_states[{bone}]: unknown state {state!r}, expected one of {names}") from err
