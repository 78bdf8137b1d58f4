"""Actuator goals from a solve: the solved rotation of a joint relative to its parent,
projected on the servo's axis, through the servo's calibration, as goal ticks.

The solver's ``T`` is (4m, 3): handle j maps a rest point v to ``[v 1] @ T[4j:4j+4]``, so its
linear part acting on column vectors is ``A_j = T[4j:4j+3].T``. Its rotation is the polar
factor ``R_j`` (SVD, det +1). The joint's rotation is ``R_rel = R_parent^T R_child`` (a root's
parent is the identity), the angle is the twist of ``R_rel`` about the servo's axis in model
space (``frames[bone] @ axis``), and ``goal = angle / (sign · 2π / 4096 / gear) + zero``.

This is the building block for ``role = "actuator"`` servos in ``live``; it holds no state
beyond preallocated work arrays.
"""

from __future__ import annotations

import numpy as np

from puppet.servo_models import TICKS_PER_TURN


def rotation_part(linear: np.ndarray) -> np.ndarray:
    """(3, 3) rotation nearest to ``linear`` (the polar factor; det +1)."""
    u, _, vt = np.linalg.svd(linear)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1.0
        r = u @ vt
    return r


def twist_angle(rotation: np.ndarray, axis: np.ndarray) -> float:
    """Radians (-π, π] that ``rotation`` (3, 3) turns about unit ``axis`` (3,) (swing-twist:
    the rotation's quaternion projected on the axis)."""
    r = rotation
    w = 0.5 * np.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2]))
    if w > 1e-6:
        v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / (4.0 * w)
    else:  # a half turn: the vector part from the diagonal
        v = np.sqrt(np.maximum(0.0, (np.diag(r) + 1.0) / 2.0))
        k = int(np.argmax(v))
        for j in range(3):
            if j != k:
                v[j] = np.copysign(v[j], r[k, j] + r[j, k])
    angle = 2.0 * np.arctan2(float(v @ axis), w)
    return float((angle + np.pi) % (2.0 * np.pi) - np.pi) if angle > np.pi else float(angle)


class ActuatorGoals:
    """Goal ticks for actuator servos from the solver's ``T``.

    servos: the actuator servo definitions (id, joint, axis, sign, gear, zero_ticks, limits).
    skeleton: the rig's skeleton (names, parents, frames).
    zero: (k,) zero ticks in use for those servos (the calibration's).

    ``goals(T)`` -> (k,) float goal ticks, clamped to each servo's joint limits;
    ``angles`` (k,) the unclamped solved joint angles of the last call, radians.
    """

    def __init__(self, servos, skeleton, zero) -> None:
        self.ids = np.array([s.id for s in servos], np.int64)
        self.bones = np.array([skeleton.index(s.joint) for s in servos], np.int64)
        self.parents = np.array([skeleton.parents[b] for b in self.bones], np.int64)
        self.axes = np.array([skeleton.frames[b] @ np.asarray(s.axis, float)
                              for b, s in zip(self.bones, servos)])
        self.scale = np.array([s.sign * 2 * np.pi / TICKS_PER_TURN / s.gear for s in servos])
        self.zero = np.asarray(zero, float)
        self.lo = np.array([s.limits[0] for s in servos])
        self.hi = np.array([s.limits[1] for s in servos])
        self.angles = np.zeros(len(servos))
        self._goals = np.zeros(len(servos))

    def goals(self, T: np.ndarray) -> np.ndarray:
        """(k,) goal ticks from the solver's (4m, 3) ``T`` (reused array: copy to keep)."""
        for n, (bone, parent) in enumerate(zip(self.bones, self.parents)):
            child = rotation_part(np.asarray(T[4 * bone:4 * bone + 3], float).T)
            if parent >= 0:
                child = rotation_part(np.asarray(T[4 * parent:4 * parent + 3], float).T).T @ child
            self.angles[n] = twist_angle(child, self.axes[n])
        np.clip(self.angles, self.lo, self.hi, out=self._goals)
        self._goals /= self.scale
        self._goals += self.zero
        return self._goals
