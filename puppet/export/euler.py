"""Rotation matrices to and from Euler angles in any of the six Tait-Bryan orders.

Convention (BVH's): order "ZXY" with angles (a, b, c) is R = Rz(a) @ Rx(b) @ Ry(c), acting on
column vectors; angles in radians here (BVH files hold degrees).
"""

from __future__ import annotations

import numpy as np

ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
_AXIS = {"X": 0, "Y": 1, "Z": 2}


def _check_order(order: str) -> tuple[int, int, int]:
    if order not in ORDERS:
        raise ValueError(f"Euler order must be one of {ORDERS}, got {order!r}")
    return tuple(_AXIS[a] for a in order)


def axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations by angle (radians, (...)) about axis 0=X, 1=Y, 2=Z."""
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(angle.shape + (3, 3))
    u, v = (axis + 1) % 3, (axis + 2) % 3
    R[..., axis, axis] = 1.0
    R[..., u, u] = c
    R[..., v, v] = c
    R[..., u, v] = -s
    R[..., v, u] = s
    return R


def euler_to_matrix(angles: np.ndarray, order: str = "ZXY") -> np.ndarray:
    """(..., 3) angles in radians, in the axes' order -> (..., 3, 3) rotation matrices."""
    i, j, k = _check_order(order)
    angles = np.asarray(angles, dtype=np.float64)
    return (
        axis_rotation(i, angles[..., 0])
        @ axis_rotation(j, angles[..., 1])
        @ axis_rotation(k, angles[..., 2])
    )


def matrix_to_euler(R: np.ndarray, order: str = "ZXY") -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) angles in radians, in the axes' order.

    The middle angle is in [-pi/2, pi/2], the others in (-pi, pi]; at gimbal lock (middle angle
    +-pi/2) the last angle is 0. euler_to_matrix(matrix_to_euler(R)) reproduces R.
    """
    i, j, k = _check_order(order)
    R = np.asarray(R, dtype=np.float64)
    s = 1.0 if (j - i) % 3 == 1 else -1.0  # +1 for the cyclic orders XYZ, YZX, ZXY
    cos_b = np.hypot(R[..., i, i], R[..., i, j])
    b = np.arctan2(s * R[..., i, k], cos_b)
    locked = cos_b < 1e-9
    a = np.where(
        locked,
        np.arctan2(s * R[..., k, j], R[..., j, j]),
        np.arctan2(-s * R[..., j, k], R[..., k, k]),
    )
    c = np.where(locked, 0.0, np.arctan2(-s * R[..., i, j], R[..., i, i]))
    return np.stack([a, b, c], axis=-1)
