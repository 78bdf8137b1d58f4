"""Actuator goals from a solved T, against scipy's rotations as the independent reference."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from puppet.drive.actuate import ActuatorGoals, rotation_part, twist_angle


def test_rotation_part_removes_scale_and_shear():
    rng = np.random.default_rng(3)
    for _ in range(20):
        r = Rotation.random(random_state=rng).as_matrix()
        s = np.eye(3) + 0.2 * (lambda a: a + a.T)(rng.normal(size=(3, 3)))  # symmetric stretch
        s = s @ s.T  # positive definite
        np.testing.assert_allclose(rotation_part(r @ s), r, atol=1e-9)


def test_twist_angle_is_the_rotation_about_the_axis():
    rng = np.random.default_rng(4)
    for _ in range(50):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(-3.0, 3.0)
        twist = Rotation.from_rotvec(axis * angle)
        # A swing about an axis perpendicular to ``axis`` does not change the twist.
        perp = np.cross(axis, rng.normal(size=3))
        perp /= np.linalg.norm(perp)
        swing = Rotation.from_rotvec(perp * rng.uniform(-0.8, 0.8))
        got = twist_angle((swing * twist).as_matrix(), axis)
        assert abs(got - angle) < 1e-9


def test_actuator_goals_invert_the_calibration(rig):
    sk = rig.skeleton
    servo = rig.servo_map.servos[0]  # neck: a root-level joint of the critter
    k_bones = sk.bone_count
    bone = sk.index(servo.joint)
    parent = sk.parents[bone]
    angle = np.radians(25.0)
    world_axis = sk.frames[bone] @ servo.axis
    T = np.zeros((4 * k_bones, 3))
    for b in range(k_bones):
        T[4 * b:4 * b + 3] = np.eye(3)
    parent_rot = Rotation.from_rotvec([0.1, -0.3, 0.2]).as_matrix()
    chain = parent_rot @ Rotation.from_rotvec(world_axis * angle).as_matrix()
    if parent >= 0:
        T[4 * parent:4 * parent + 3] = parent_rot.T
        T[4 * bone:4 * bone + 3] = chain.T
    else:
        T[4 * bone:4 * bone + 3] = Rotation.from_rotvec(world_axis * angle).as_matrix().T
    goals = ActuatorGoals([servo], sk, [servo.zero_ticks])
    got = goals.goals(T)
    want = rig.servo_map.ticks_for(np.r_[angle, np.zeros(len(rig.servo_map.ids) - 1)])[0]
    assert abs(got[0] - want) < 0.5
    assert abs(goals.angles[0] - angle) < 1e-6  # float32 polar factors, as the solver's T
