"""Actuator goals from a solve: the solved rotation of a joint relative to its parent,
projected on the servo's axis, through the servo's calibration, as goal ticks.

The solver's ``T`` is (4m, 3): handle j maps a rest point v to ``[v 1] @ T[4j:4j+4]``, so its
linear part acting on column vectors is ``A_j = T[4j:4j+3].T``. Its rotation is the polar
factor ``R_j`` (SVD, det +1). The joint's rotation is ``R_rel = R_parent^T R_child`` (a root's
parent is the identity), the angle is the twist of ``R_rel`` about the servo's axis in model
space (``frames[bone] @ axis``), and the goal is that angle, clamped to the servo's limits, in
ticks through its calibration (``puppet.servo_models.ServoUnits.ticks``).

This is the building block for ``role = "actuator"`` servos in ``live``; it holds no state
beyond preallocated work arrays, and its per-frame ``goals`` allocates no arrays.
"""

from __future__ import annotations

import math

import numpy as np

from puppet._native import fit_rotations
from puppet.servo_models import ServoUnits


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
    the rotation's quaternion projected on the axis). Scalar arithmetic only (no arrays)."""
    r = rotation
    trace = float(r[0, 0] + r[1, 1] + r[2, 2])
    w = 0.5 * math.sqrt(max(0.0, 1.0 + trace))
    if w > 1e-6:
        vx = float(r[2, 1] - r[1, 2]) / (4.0 * w)
        vy = float(r[0, 2] - r[2, 0]) / (4.0 * w)
        vz = float(r[1, 0] - r[0, 1]) / (4.0 * w)
    else:  # a half turn: the vector part from the diagonal, signs from the symmetric part
        v = [math.sqrt(max(0.0, (float(r[i, i]) + 1.0) / 2.0)) for i in range(3)]
        big = max(range(3), key=v.__getitem__)
        for j in range(3):
            if j != big:
                v[j] = math.copysign(v[j], float(r[big, j] + r[j, big]))
        vx, vy, vz = v
    along = vx * float(axis[0]) + vy * float(axis[1]) + vz * float(axis[2])
    angle = 2.0 * math.atan2(along, w)
    return (angle + math.pi) % (2.0 * math.pi) - math.pi if angle > math.pi else angle


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
        self.units = ServoUnits.for_servos(servos, np.asarray(zero, np.int64))
        self.lo, self.hi = self.units.lo, self.units.hi
        self.angles = np.zeros(len(servos))
        self._goals = np.zeros(len(servos))
        # Work arrays of the per-frame path: the (3, 3) row blocks of T for each servo's bone
        # and parent (a root's parent block is the identity), their polar factors, the relative
        # rotation, all allocated once.
        k = len(servos)
        rows = [np.arange(4 * b, 4 * b + 3) if b >= 0 else np.full(3, -1) for b in
                np.concatenate([self.bones, self.parents])]
        rows = np.concatenate(rows).astype(np.int64)
        self._rows = np.maximum(rows, 0)  # a root's parent rows are overwritten below
        self._root_rows = np.flatnonzero(rows < 0)
        self._root_fill = _IDENTITY_ROWS[self._root_rows % 3]
        self._blocks = np.zeros((2 * k, 3, 3), np.float32)
        self._polar = np.zeros((2 * k, 3, 3), np.float32)
        self._rel = np.zeros((3, 3))

    def goals(self, T: np.ndarray) -> np.ndarray:
        """(k,) goal ticks from the solver's (4m, 3) ``T`` (reused array: copy to keep).

        Allocates no arrays: the blocks of T are gathered into a work array and their polar
        factors come from the native ``fit_rotations`` (GIL released)."""
        k = len(self.bones)
        flat = self._blocks.reshape(6 * k, 3)
        np.take(T, self._rows, axis=0, out=flat)
        if len(self._root_rows):
            flat[self._root_rows] = self._root_fill
        fit_rotations(self._blocks, self._polar)  # Q = polar(T block) = R^T of the linear part
        for n in range(k):
            # R_rel = R_parent^T R_child = Q_parent Q_child^T
            np.matmul(self._polar[k + n], self._polar[n].T, out=self._rel)
            self.angles[n] = twist_angle(self._rel, self.axes[n])
        np.clip(self.angles, self.lo, self.hi, out=self._goals)
        return self.units.ticks(self._goals, out=self._goals)


_IDENTITY_ROWS = np.eye(3, dtype=np.float32)
