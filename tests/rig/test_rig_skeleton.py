"""Forward kinematics of known poses, against hand-computed transforms."""

import numpy as np
import pytest

from puppet.rig import RigError, Skeleton
from puppet.rig.skeleton import Joint, axis_angle_matrices, frame_from_direction


def chain(joints=()):
    """Three bones along +Y: root at origin, mid at y=1, tip at y=2."""
    heads = np.array([[0, 0, 0], [0, 1, 0], [0, 2, 0]], float)
    tails = heads + [0, 1, 0]
    frames = np.tile(np.eye(3), (3, 1, 1))
    return Skeleton(("root", "mid", "tip"), np.array([-1, 0, 1]), heads, tails, frames, tuple(joints))


def apply(T, p):
    return T[:, :3] @ p + T[:, 3]


def test_rest_angles_give_identity_transforms():
    sk = chain([Joint(1, np.array([[0, 0, 1.0]]), np.array([0]))])
    np.testing.assert_allclose(sk.pose(np.zeros(1)), sk.rest_pose(), atol=1e-15)


def test_single_hinge_rotates_children_about_its_pivot():
    sk = chain([Joint(1, np.array([[0, 0, 1.0]]), np.array([0]))])
    T = sk.pose(np.array([np.pi / 2]))
    # root untouched; mid rotates 90° about +Z through (0,1,0): its tip (0,2,0) goes to (-1,1,0).
    np.testing.assert_allclose(T[0], sk.rest_pose()[0], atol=1e-12)
    np.testing.assert_allclose(apply(T[1], [0, 2, 0]), [-1, 1, 0], atol=1e-12)
    np.testing.assert_allclose(apply(T[1], [0, 1, 0]), [0, 1, 0], atol=1e-12)
    # the child follows rigidly: its tip (0,3,0) goes to (-2,1,0).
    np.testing.assert_allclose(apply(T[2], [0, 3, 0]), [-2, 1, 0], atol=1e-12)


def test_two_joints_compose_down_the_chain():
    sk = chain([Joint(0, np.array([[0, 0, 1.0]]), np.array([0])),
                Joint(2, np.array([[0, 0, 1.0]]), np.array([1]))])
    T = sk.pose(np.array([np.pi / 2, -np.pi / 2]))
    # root turns the whole chain to point along -X; the tip joint turns it back to +Y.
    np.testing.assert_allclose(apply(T[2], [0, 2, 0]), [-2, 0, 0], atol=1e-12)
    np.testing.assert_allclose(apply(T[2], [0, 3, 0]), [-2, 1, 0], atol=1e-12)
    np.testing.assert_allclose(T[2][:, :3], np.eye(3), atol=1e-12)


def test_axes_compose_in_declared_order_in_the_bone_frame():
    # Bone frame rotated so local x = model z: an axis "x" in the bone frame is model z.
    frame = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], float).T  # columns: x->Z, y->X, z->Y
    assert np.isclose(np.linalg.det(frame), 1)
    sk = Skeleton(("b",), [-1], [[0, 0, 0]], [[1, 0, 0]], [frame],
                  (Joint(0, np.array([[1.0, 0, 0], [0, 1.0, 0]]), np.array([0, 1])),))
    a, b = 0.3, -0.7
    T = sk.pose(np.array([a, b]))
    q = axis_angle_matrices(np.eye(3)[:2], np.array([a, b]))
    expected = frame @ (q[0] @ q[1]) @ frame.T
    np.testing.assert_allclose(T[0][:, :3], expected, atol=1e-12)
    assert not np.allclose(expected, frame @ (q[1] @ q[0]) @ frame.T)


def test_random_poses_are_rigid_and_keep_joints_connected():
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(3, 3, 3))
    axes /= np.linalg.norm(axes, axis=2, keepdims=True)
    sk = chain([Joint(i, axes[i], np.arange(3 * i, 3 * i + 3)) for i in range(3)])
    T = sk.pose(rng.uniform(-2, 2, 9))
    for t in T:
        np.testing.assert_allclose(t[:, :3] @ t[:, :3].T, np.eye(3), atol=1e-12)
        assert np.linalg.det(t[:, :3]) == pytest.approx(1.0)
    # joints stay connected: each child's pivot is where its parent takes it.
    for i in (1, 2):
        np.testing.assert_allclose(apply(T[i], sk.heads[i]), apply(T[i - 1], sk.heads[i]), atol=1e-12)


def test_joint_needs_one_to_three_axes():
    with pytest.raises(RigError, match="needs 1-3 axes"):
        chain([Joint(1, np.eye(3)[[0, 1, 2, 0]], np.arange(4))])


def test_pose_writes_into_out_buffer():
    sk = chain([Joint(1, np.array([[1.0, 0, 0]]), np.array([0]))])
    out = np.empty((3, 3, 4))
    assert sk.pose(np.array([0.4]), out) is out


def test_frame_from_direction_is_orthonormal_with_y_along_bone():
    f = frame_from_direction(np.array([0.0, -2.0, 0.0]))
    np.testing.assert_allclose(f[:, 1], [0, -1, 0])
    np.testing.assert_allclose(f.T @ f, np.eye(3), atol=1e-12)
    assert np.linalg.det(f) == pytest.approx(1.0)


def test_parents_must_come_first():
    with pytest.raises(RigError, match="parents must come before children"):
        Skeleton(("a", "b"), [1, -1], np.zeros((2, 3)), np.ones((2, 3)), np.tile(np.eye(3), (2, 1, 1)))


def test_duplicate_bone_names_are_refused():
    with pytest.raises(RigError, match="duplicate bone names"):
        Skeleton(("a", "a"), [-1, 0], np.zeros((2, 3)), np.ones((2, 3)), np.tile(np.eye(3), (2, 1, 1)))


def test_rest_frames_must_be_rotations():
    with pytest.raises(RigError, match="rest frame of bone 'b' is not a rotation"):
        Skeleton(("a", "b"), [-1, 0], np.zeros((2, 3)), np.ones((2, 3)), [np.eye(3), np.diag([1, 1, -1.0])])


def reference_pose(parents, heads, frames, joints, angles):
    """Plain NumPy forward kinematics, straight from the module's conventions: per bone
    Q = prod R(axis_i, a_i) in the rest frame, R = B Q Bᵀ, then A = A_p R, t = A_p (h − R h) + t_p."""
    b = len(parents)
    rot = np.tile(np.eye(3), (b, 1, 1))
    for j in joints:
        q = np.eye(3)
        for axis, dof in zip(j.axes, j.dofs):
            x, y, z = axis
            k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
            a = angles[dof]
            q = q @ (np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k)
        rot[j.bone] = frames[j.bone] @ q @ frames[j.bone].T
    pose = np.zeros((b, 3, 4))
    for i, p in enumerate(parents):
        A, t = (np.eye(3), np.zeros(3)) if p < 0 else (pose[p, :, :3], pose[p, :, 3])
        pose[i, :, :3] = A @ rot[i]
        pose[i, :, 3] = A @ (heads[i] - rot[i] @ heads[i]) + t
    return rot, pose


def random_skeleton(rng, bones=12):
    """A random tree (parents before children) with random rest frames, about two thirds of the
    bones jointed with 1-3 random axes reading shuffled angle indices."""
    parents = np.array([-1] + [int(rng.integers(0, i)) for i in range(1, bones)])
    heads = rng.normal(size=(bones, 3))
    frames = np.linalg.qr(rng.normal(size=(bones, 3, 3)))[0]
    frames[:, :, 0] *= np.sign(np.linalg.det(frames))[:, None]  # proper rotations
    jointed = [i for i in range(bones) if rng.random() < 0.67]
    counts = [int(rng.integers(1, 4)) for _ in jointed]
    dofs = rng.permutation(sum(counts))
    joints, start = [], 0
    for bone, n in zip(rng.permutation(jointed), counts):  # joints listed in no bone order
        axes = rng.normal(size=(n, 3))
        joints.append(Joint(int(bone), axes / np.linalg.norm(axes, axis=1, keepdims=True), dofs[start:start + n]))
        start += n
    names = tuple(f"b{i}" for i in range(bones))
    return Skeleton(names, parents, heads, heads + 1.0, frames, tuple(joints))


@pytest.mark.parametrize("seed", range(5))
def test_native_forward_kinematics_matches_a_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    sk = random_skeleton(rng)
    assert {len(j.dofs) for j in sk.joints} <= {1, 2, 3} and len(sk.joints) > 0
    for _ in range(10):
        angles = rng.uniform(-np.pi, np.pi, sk.dof_count)
        rot_ref, pose_ref = reference_pose(sk.parents, sk.heads, sk.frames, sk.joints, angles)
        rot = np.empty((sk.bone_count, 3, 3))
        assert sk.joint_rotations(angles, rot) is rot
        np.testing.assert_allclose(rot, rot_ref, rtol=0, atol=1e-12)
        pose = np.empty((sk.bone_count, 3, 4))
        assert sk.pose_from_rotations(rot_ref, pose) is pose
        np.testing.assert_allclose(pose, pose_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(sk.pose(angles), pose_ref, rtol=0, atol=1e-12)
        rot_too = np.empty((sk.bone_count, 3, 3))
        np.testing.assert_allclose(sk.pose(angles, pose, rotations=rot_too), pose_ref, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(rot_too, rot)


def test_forward_kinematics_needs_every_angle_its_axes_read():
    sk = chain([Joint(1, np.array([[0, 0, 1.0]]), np.array([2]))])
    with pytest.raises(ValueError, match="reads angle 2, angles has 2 entries"):
        sk.pose(np.zeros(2))


def test_forward_kinematics_refuses_a_wrong_out_buffer():
    sk = chain([Joint(1, np.array([[0, 0, 1.0]]), np.array([0]))])
    with pytest.raises(TypeError, match="incompatible function arguments"):
        sk.pose(np.zeros(1), np.empty((3, 3, 4), np.float32))
