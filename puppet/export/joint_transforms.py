"""Rigid joint transforms from FAST's affine handle transforms (polar decomposition).

FAST gives every handle an affine map ``x -> A_j x + t_j`` of rest points to posed points
(``T`` rows ``4j..4j+2`` hold ``A_jᵀ``, row ``4j+3`` holds ``t_j``). A skeleton file needs a
rigid transform per joint. For bone j (handle j) with rest pivot ``p_j``:

    R_j  = polar(A_j)                 the rotation of A_j = R_j S_j (S_j symmetric), det +1
    c_j  = A_j p_j + t_j              where the solve puts the joint's pivot
    P_j  = [R_j | c_j − R_j p_j]      the rigid map of rest points: rotates about the pivot,
                                      then lands the pivot at c_j

For a sensed bone whose whole chain is sensed, A_j is already a rotation and P_j is exactly the
forward kinematics. Extra-weight handles (after the bones) have no joint and are not used.
"""

from __future__ import annotations

import numpy as np


def polar_rotations(A: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(b, 3, 3) rotations nearest to A (b, 3, 3) in Frobenius norm: A = R S, det R = +1.

    Reflections (det A < 0) and rank deficiency give the nearest proper rotation.
    """
    U, _, Vt = np.linalg.svd(A)
    d = np.sign(np.linalg.det(U @ Vt))
    d[d == 0] = 1.0
    U[:, :, 2] *= d[:, None]
    return np.matmul(U, Vt, out=out)


class JointTransforms:
    """Per-frame rigid world transforms of a skeleton's joints from a FAST ``T``.

    heads:  (b, 3) float64 rest pivots of the bones (handles 0..b-1), model units.
    After ``update(T)``:
      affine:    (b, 3, 4) float64 handle affines [A_j | t_j].
      rotation:  (b, 3, 3) float64 R_j, each joint's world rotation relative to rest.
      pivot:     (b, 3) float64 c_j, where the solve puts each pivot.
      world:     (b, 3, 4) float64 P_j = [R_j | c_j − R_j p_j], rest points -> posed points.
    """

    def __init__(self, heads: np.ndarray):
        self.heads = np.ascontiguousarray(heads, np.float64)
        b = len(self.heads)
        self.b = b
        self.affine = np.zeros((b, 3, 4))
        self.rotation = np.tile(np.eye(3), (b, 1, 1))
        self.pivot = self.heads.copy()
        self.world = np.zeros((b, 3, 4))
        self.world[:, :, :3] = np.eye(3)

    def update(self, T: np.ndarray) -> "JointTransforms":
        """Fill the fields from T (4m, 3), m >= b (extra handles after the bones are ignored)."""
        b = self.b
        Tb = np.asarray(T).reshape(-1, 4, 3)[:b]
        self.affine[:, :, :3] = np.swapaxes(Tb[:, :3, :], 1, 2)
        self.affine[:, :, 3] = Tb[:, 3, :]
        A = self.affine[:, :, :3]
        polar_rotations(A, out=self.rotation)
        np.einsum("bij,bj->bi", A, self.heads, out=self.pivot)
        self.pivot += self.affine[:, :, 3]
        self.world[:, :, :3] = self.rotation
        self.world[:, :, 3] = self.pivot - np.einsum("bij,bj->bi", self.rotation, self.heads)
        return self


def rigid_inverse(M: np.ndarray) -> np.ndarray:
    """Inverse of rigid (..., 3, 4) transforms [R | t] -> [Rᵀ | −Rᵀ t]."""
    R = np.swapaxes(M[..., :3], -1, -2)
    out = np.empty_like(M)
    out[..., :3] = R
    out[..., 3] = -np.einsum("...ij,...j->...i", R, M[..., 3])
    return out


def compose(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(..., 3, 4) affine A ∘ B (apply B first)."""
    out = np.empty(np.broadcast_shapes(A.shape, B.shape))
    out[..., :3] = A[..., :3] @ B[..., :3]
    out[..., 3] = np.einsum("...ij,...j->...i", A[..., :3], B[..., 3]) + A[..., 3]
    return out


def rest_globals(heads: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """(b, 3, 4) rest world transforms of the joints: rotation = rest frame, origin = pivot."""
    G = np.empty((len(heads), 3, 4))
    G[:, :, :3] = frames
    G[:, :, 3] = heads
    return G


def local_transforms(world: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(b, 3, 4) parent-relative transforms of rigid world transforms (roots: their world)."""
    parents = np.asarray(parents)
    out = np.array(world, dtype=np.float64, copy=True)
    has = parents >= 0
    if has.any():
        out[has] = compose(rigid_inverse(world[parents[has]]), world[has])
    return out


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 4) unit quaternions (x, y, z, w), w >= 0 (Shepperd)."""
    R = np.asarray(R, np.float64)
    shape = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    q = np.empty((len(R), 4))
    tr = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    diag = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2], tr], 1)
    k = diag.argmax(1)
    for case in range(4):
        sel = k == case
        if not sel.any():
            continue
        r = R[sel]
        if case == 3:
            s = 2.0 * np.sqrt(1.0 + tr[sel])
            q[sel] = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                               (r[:, 1, 0] - r[:, 0, 1]) / s, 0.25 * s], 1)
        else:
            i, j, l = case, (case + 1) % 3, (case + 2) % 3
            s = 2.0 * np.sqrt(np.maximum(1.0 + r[:, i, i] - r[:, j, j] - r[:, l, l], 1e-300))
            v = np.empty((len(r), 4))
            v[:, i] = 0.25 * s
            v[:, j] = (r[:, j, i] + r[:, i, j]) / s
            v[:, l] = (r[:, l, i] + r[:, i, l]) / s
            v[:, 3] = (r[:, l, j] - r[:, j, l]) / s
            q[sel] = v
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(shape + (4,))
