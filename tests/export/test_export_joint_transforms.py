"""Joint transforms from FAST handles: polar decomposition, pivots, quaternions."""

import numpy as np
from scipy.spatial.transform import Rotation

from puppet.export import JointTransforms, polar_rotations
from puppet.export.joint_transforms import local_transforms, matrix_to_quaternion


def test_polar_rotation_of_rotation_times_stretch():
    R = Rotation.random(50, random_state=2).as_matrix()
    rng = np.random.default_rng(0)
    Q = Rotation.random(50, random_state=3).as_matrix()
    S = Q @ np.apply_along_axis(np.diag, 1, rng.uniform(0.5, 1.5, (50, 3))) @ np.swapaxes(Q, 1, 2)
    np.testing.assert_allclose(polar_rotations(R @ S), R, atol=1e-12)
    flipped = polar_rotations(R @ np.diag([1.0, 1.0, -0.2]))  # a reflection gives a proper rotation
    np.testing.assert_allclose(np.linalg.det(flipped), 1.0, atol=1e-12)


def test_pivots_land_where_the_handle_puts_them():
    heads = np.array([[0.0, 1.0, 0.0], [0.2, 1.5, -0.1]])
    rng = np.random.default_rng(4)
    A = Rotation.random(2, random_state=5).as_matrix() * rng.uniform(0.8, 1.2, (2, 1, 1))
    t = rng.normal(size=(2, 3))
    T = np.zeros((2, 4, 3), np.float32)
    T[:, :3, :] = np.swapaxes(A, 1, 2)
    T[:, 3, :] = t
    joints = JointTransforms(heads).update(T.reshape(8, 3))
    expected_pivots = np.einsum("bij,bj->bi", A, heads) + t
    np.testing.assert_allclose(joints.pivot, expected_pivots, atol=1e-5)
    landed = np.einsum("bij,bj->bi", joints.world[:, :, :3], heads) + joints.world[:, :, 3]
    np.testing.assert_allclose(landed, expected_pivots, atol=1e-5)
    np.testing.assert_allclose(joints.rotation, polar_rotations(A.astype(np.float32)), atol=1e-6)


def test_rigid_handles_reproduce_forward_kinematics(critter):
    """A T built from the skeleton's forward kinematics comes back as that pose exactly."""
    rng = np.random.default_rng(6)
    angles = rng.uniform(-0.6, 0.6, len(critter.servo_map))
    pose = critter.pose(angles)  # (b, 3, 4)
    b = len(pose)
    T = np.zeros((b, 4, 3))
    T[:, :3, :] = np.swapaxes(pose[:, :, :3], 1, 2)
    T[:, 3, :] = pose[:, :, 3]
    joints = JointTransforms(critter.skeleton.heads).update(T.reshape(4 * b, 3))
    np.testing.assert_allclose(joints.world, pose, atol=1e-12)


def test_quaternions_against_scipy_and_local_transforms():
    R = Rotation.random(300, random_state=9).as_matrix()
    q = matrix_to_quaternion(R)
    ref = Rotation.from_matrix(R).as_quat()  # x, y, z, w
    ref *= np.where(ref[:, 3:] < 0, -1, 1)
    np.testing.assert_allclose(q, ref, atol=1e-12)
    world = np.zeros((3, 3, 4))
    world[:, :, :3] = R[:3]
    world[:, :, 3] = [[1, 2, 3], [0, 1, 0], [4, 0, 0]]
    local = local_transforms(world, np.array([-1, 0, 1]))
    rebuilt = world[0, :, :3] @ local[1, :, :3]
    np.testing.assert_allclose(rebuilt, world[1, :, :3], atol=1e-12)
    np.testing.assert_allclose(world[0, :, :3] @ local[1, :, 3] + world[0, :, 3], world[1, :, 3],
                               atol=1e-12)
