"""Skeleton: bones in a tree with rest frames, joints with 1-3 axes, forward kinematics.

Conventions (all in model units and radians):
- Bone b has a rest pivot ``heads[b]`` (3,) where its joint sits, a rest tip ``tails[b]`` (3,),
  and a rest frame ``frames[b]`` (3, 3) whose columns are the bone's local x, y, z axes in
  model space (orthonormal, det +1).
- A joint belongs to one bone and rotates it relative to its parent about the bone's pivot.
  Its axes are unit vectors in the bone's rest frame, composed in declared order:
  ``Q = R(axis_0, a_0) @ R(axis_1, a_1) @ ...`` (the first axis is outermost, as in intrinsic
  Euler angles). In model space the joint rotation is ``R_b = B_b Q B_bᵀ``.
- Each axis reads one entry of the joint-angle vector (``dofs``); a rig's angle vector is in
  servo-map order, so ``skeleton.pose(servo_map.angles(ticks))`` is the whole forward path.
- A bone's pose is the 3x4 affine ``[A_b | t_b]`` mapping rest points to posed points:
  ``A_b = A_p R_b``, ``t_b = A_p (p_b − R_b p_b) + t_p`` (p = parent; identity above roots).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from puppet import _kinematics
from puppet.rig.errors import RigError


@dataclass(frozen=True)
class Joint:
    """Sensed rotation axes of one bone.

    bone: index of the bone this joint rotates.
    axes: (a, 3) float64 unit axes in the bone's rest frame, 1 <= a <= 3, in composition order.
    dofs: (a,) int64 indices into the joint-angle vector, one per axis.
    """

    bone: int
    axes: np.ndarray
    dofs: np.ndarray


def axis_angle_matrices(axes: np.ndarray, angles: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Rodrigues rotation matrices.

    axes: (k, 3) unit axes; angles: (k,) radians; out: optional (k, 3, 3) float64.
    Returns (k, 3, 3): rotation by ``angles[i]`` about ``axes[i]`` (right-handed).
    """
    k = len(angles)
    if out is None:
        out = np.empty((k, 3, 3))
    c = np.cos(angles)[:, None, None]
    s = np.sin(angles)[:, None, None]
    x, y, z = axes[:, 0], axes[:, 1], axes[:, 2]
    cross = np.zeros((k, 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -z, y, -x
    cross[:, 1, 0], cross[:, 2, 0], cross[:, 2, 1] = z, -y, x
    outer = axes[:, :, None] * axes[:, None, :]
    np.multiply(c, np.eye(3), out=out)
    out += s * cross + (1.0 - c) * outer
    return out


def frame_from_direction(direction: np.ndarray, up_hint: np.ndarray | None = None) -> np.ndarray:
    """A rest frame (3, 3) whose y column points along ``direction`` (3,).

    x is the hint (default model +X, else +Z) made orthogonal to y; z = x × y. Zero-length
    directions (point handles) get the identity frame.
    """
    length = float(np.linalg.norm(direction))
    if length < 1e-12:
        return np.eye(3)
    y = np.asarray(direction, float) / length
    for hint in ([up_hint] if up_hint is not None else []) + [np.array([1.0, 0, 0]), np.array([0, 0, 1.0])]:
        x = hint - np.dot(hint, y) * y
        if np.linalg.norm(x) > 1e-6:
            break
    x = x / np.linalg.norm(x)
    z = np.cross(x, y)
    return np.column_stack([x, y, z])


@dataclass(frozen=True)
class Skeleton:
    """Bones in a tree (parents before children) with rest frames and sensed joints.

    names:   bone names, unique.
    parents: (b,) int64, parent bone index or -1 for a root; parents[i] < i.
    heads:   (b, 3) float64 rest pivots (joint positions), model units.
    tails:   (b, 3) float64 rest tips (equal to heads for point handles).
    frames:  (b, 3, 3) float64 rest frames, columns = local x, y, z in model space.
    joints:  sensed joints (at most one per bone); ``dof_count`` angles drive them.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    frames: np.ndarray
    joints: tuple[Joint, ...] = ()
    _index: dict = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        b = len(self.names)
        parents = np.asarray(self.parents, np.int64).reshape(-1)
        heads = np.asarray(self.heads, np.float64).reshape(-1, 3)
        tails = np.asarray(self.tails, np.float64).reshape(-1, 3)
        frames = np.asarray(self.frames, np.float64).reshape(-1, 3, 3)
        if not (len(parents) == len(heads) == len(tails) == len(frames) == b):
            raise RigError(f"skeleton arrays disagree: {b} names, {len(parents)} parents, "
                           f"{len(heads)} heads, {len(tails)} tails, {len(frames)} frames",
                           field="skeleton")
        if len(set(self.names)) != b:
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise RigError(f"duplicate bone names {dup}", field="skeleton.names")
        for i, p in enumerate(parents):
            if not (-1 <= p < i):
                raise RigError(f"bone {self.names[i]!r} has parent {int(p)}; parents must come "
                               "before children", field="skeleton.parents")
        gram = np.einsum("bji,bjk->bik", frames, frames)
        bad = np.flatnonzero((np.abs(gram - np.eye(3)).max(axis=(1, 2)) > 1e-6)
                             | (np.linalg.det(frames) < 0)) if b else []
        if len(bad):
            raise RigError(f"rest frame of bone {self.names[bad[0]]!r} is not a rotation "
                           "(orthonormal, det +1)", field="skeleton.frames")
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "heads", heads)
        object.__setattr__(self, "tails", tails)
        object.__setattr__(self, "frames", frames)
        object.__setattr__(self, "_index", {n: i for i, n in enumerate(self.names)})
        self._prepare_pose()

    # ---- structure ------------------------------------------------------------------------
    @property
    def bone_count(self) -> int:
        return len(self.names)

    @property
    def dof_count(self) -> int:
        """Length of the joint-angle vector: one past the largest dof index."""
        return int(max((int(j.dofs.max()) + 1 for j in self.joints), default=0))

    def index(self, name: str) -> int:
        """Bone index of ``name``; KeyError naming the known bones otherwise."""
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"no bone named {name!r}; bones are {list(self.names)}") from None

    def children(self, bone: int) -> list[int]:
        return [i for i, p in enumerate(self.parents) if p == bone]

    def with_joints(self, joints: tuple[Joint, ...]) -> "Skeleton":
        """The same bones with these sensed joints."""
        return replace(self, joints=tuple(joints))

    # ---- forward kinematics ---------------------------------------------------------------
    def _prepare_pose(self) -> None:
        """Constant arrays of the native forward kinematics (solver_native forward_kinematics.h)."""
        b = len(self.names)
        by_bone: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for j in self.joints:
            a = np.asarray(j.axes, float).reshape(-1, 3)
            dofs = np.asarray(j.dofs, np.int64).reshape(-1)
            if not 1 <= len(a) <= 3 or len(a) != len(dofs):
                raise RigError(f"joint of bone {self.names[j.bone]!r} needs 1-3 axes, one dof each",
                               field="skeleton.joints")
            if not 0 <= j.bone < b:
                raise RigError(f"a joint names bone {j.bone}; the skeleton has {b} bones", field="skeleton.joints")
            if (dofs < 0).any():
                raise RigError(f"joint of bone {self.names[j.bone]!r} reads a negative angle index {dofs.min()}",
                               field="skeleton.joints")
            if j.bone in by_bone:
                raise RigError(f"bone {self.names[j.bone]!r} has two joints", field="skeleton.joints")
            by_bone[j.bone] = (a @ self.frames[j.bone].T, dofs)  # axes in model space: B a
        counts = np.array([len(by_bone[i][1]) if i in by_bone else 0 for i in range(b)], np.int32)
        axes = [by_bone[i][0] for i in sorted(by_bone)]
        dofs = [by_bone[i][1] for i in sorted(by_bone)]
        work = {
            # (k, 3) model-space axes grouped by bone, composition order within a bone;
            # (k,) int32 the angle each reads; (b + 1,) int32 bone i's axes are [start[i], start[i + 1]).
            "_fk_axes": np.ascontiguousarray(np.concatenate(axes) if axes else np.zeros((0, 3))),
            "_fk_axis_dof": np.concatenate(dofs).astype(np.int32) if dofs else np.zeros(0, np.int32),
            "_fk_bone_axes": np.concatenate([[0], np.cumsum(counts)]).astype(np.int32),
            "_fk_parents": self.parents.astype(np.int32),
            "_fk_heads": np.ascontiguousarray(self.heads),
            "_joint_rot": np.empty((b, 3, 3)),  # pose()'s rotations
        }
        for key, value in work.items():
            object.__setattr__(self, key, value)

    def joint_rotations(self, joint_angles: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Each bone's joint rotation in model space (native, no allocation with ``out``).

        joint_angles: (dof_count,) float64 radians. out: optional (b, 3, 3) float64 C-contiguous.
        Returns (b, 3, 3): ``R_b = B_b Q_b B_bᵀ``; identity for bones without a joint.
        """
        if out is None:
            out = np.empty((len(self.names), 3, 3))
        _kinematics.joint_rotations(np.ascontiguousarray(joint_angles, np.float64), self._fk_axes,
                                    self._fk_axis_dof, self._fk_bone_axes, out)
        return out

    def pose(self, joint_angles: np.ndarray, out: np.ndarray | None = None,
             rotations: np.ndarray | None = None) -> np.ndarray:
        """Forward kinematics (native, one call, no allocation with ``out``).

        joint_angles: (dof_count,) float64 radians (servo-map order for a rig).
        out: optional (b, 3, 4) float64 C-contiguous to write into.
        rotations: optional (b, 3, 3) float64 C-contiguous that also receives the joint rotations
                   (as :meth:`joint_rotations` writes them): rotations and poses in one call.
        Returns (b, 3, 4): bone b's affine ``[A_b | t_b]`` taking rest points to posed points.
        """
        if out is None:
            out = np.empty((len(self.names), 3, 4))
        _kinematics.forward_kinematics(np.ascontiguousarray(joint_angles, np.float64), self._fk_axes,
                                       self._fk_axis_dof, self._fk_bone_axes, self._fk_parents, self._fk_heads,
                                       self._joint_rot if rotations is None else rotations, out)
        return out

    def pose_from_rotations(self, rotations: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Forward kinematics from model-space joint rotations (b, 3, 3) float64; returns (b, 3, 4)
        float64 (into ``out`` if given, C-contiguous)."""
        if out is None:
            out = np.empty((len(self.names), 3, 4))
        _kinematics.pose_from_rotations(np.ascontiguousarray(rotations, np.float64), self._fk_parents,
                                        self._fk_heads, out)
        return out

    def rest_pose(self) -> np.ndarray:
        """(b, 3, 4) identity transforms."""
        out = np.zeros((len(self.names), 3, 4))
        out[:, :, :3] = np.eye(3)
        return out
