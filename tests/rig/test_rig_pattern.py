"""Bone classification, the constraint pattern, and per-frame values against FK."""

import numpy as np

from puppet.fast import Pattern
from puppet.rig import load_rig
from puppet.rig.skeleton import axis_angle_matrices

TICK = 2 * np.pi / 4096


def test_classification_full_relative_free(tube_rig_dir):
    rig = load_rig(tube_rig_dir / "tube.toml")
    # bone1 is the root with a servo; bone2 has none; bone3 is sensed under the free bone2.
    assert rig.bone_kinds() == {"full": ["bone1"], "relative": ["bone3"], "free": ["bone2"]}
    pattern = rig.pattern()
    assert isinstance(pattern, Pattern)
    assert pattern.full == (0,)
    assert pattern.relative == ((2, 1, (0.0, 2.0, 0.0)),)
    assert pattern.positional == (0,)


def test_fixed_bones_are_sensed_with_identity_joint(tube_rig_dir):
    text = (tube_rig_dir / "tube.toml").read_text().replace('[solver]', 'fixed = ["bone2"]\n\n[solver]')
    (tube_rig_dir / "fixed.toml").write_text(text)
    rig = load_rig(tube_rig_dir / "fixed.toml")
    assert rig.bone_kinds() == {"full": ["bone1", "bone2", "bone3"], "relative": [], "free": []}


def test_fill_values_match_forward_kinematics(tube_rig_dir):
    rig = load_rig(tube_rig_dir / "tube.toml")
    ticks = np.array([2000 + 300, 2048 + 200, 2048 - 150], np.int32)
    angles = rig.servo_map.angles(ticks)
    np.testing.assert_allclose(angles, [300 * TICK, -200 * TICK / 2, -150 * TICK])
    values = rig.pattern().values()
    rig.fill_values(angles, values)
    pose = rig.pose(angles)

    # full: [p 1] @ block == FK applied to p, for any rest point p.
    points = np.random.default_rng(0).normal(size=(20, 3))
    homogeneous = np.concatenate([points, np.ones((20, 1))], axis=1)
    expected = points @ pose[0][:, :3].T + pose[0][:, 3]
    np.testing.assert_allclose(homogeneous @ values.full[0], expected, atol=1e-5)
    # and bone1 is a rotation by 300 ticks about +Z through its head (0, 0.1, 0).
    rz = axis_angle_matrices(np.array([[0, 0, 1.0]]), np.array([300 * TICK]))[0]
    np.testing.assert_allclose(values.full[0][:3].T, rz, atol=1e-6)
    np.testing.assert_allclose(values.full[0][3], [0, 0.1, 0] - rz @ [0, 0.1, 0], atol=1e-6)

    # relative: bone3's joint rotation, composed x (servo 5) then -y (servo 6) in its rest frame
    # (which is the model frame: the bone points along +Y).
    q = axis_angle_matrices(np.array([[1.0, 0, 0], [0, -1.0, 0]]), angles[1:])
    np.testing.assert_allclose(values.relative[0], q[0] @ q[1], atol=1e-6)
    # FK satisfies the relative constraint: child linear = parent linear @ R, agreeing at the pivot.
    np.testing.assert_allclose(pose[2][:, :3], pose[1][:, :3] @ values.relative[0], atol=1e-6)
    pivot = np.array([0, 2.0, 0])
    np.testing.assert_allclose(pose[2][:, :3] @ pivot + pose[2][:, 3], pose[1][:, :3] @ pivot + pose[1][:, 3],
                               atol=1e-12)

    # positional: the pins' rest positions.
    np.testing.assert_allclose(values.positional[0], rig.V[0], atol=1e-7)


def test_calibration_file_next_to_the_rig_is_used(tube_rig_dir):
    (tube_rig_dir / "tube.calibration.toml").write_text("[zero_ticks]\n3 = 2100\n")
    rig = load_rig(tube_rig_dir / "tube.toml")
    np.testing.assert_array_equal(rig.servo_map.zero, [2100, 2048, 2048])
    np.testing.assert_allclose(rig.servo_map.angles(np.array([2100, 2048, 2048], np.int32)), 0)


def test_pin_point_snaps_to_the_nearest_vertex(tube_rig_dir):
    text = (tube_rig_dir / "tube.toml").read_text() + "\n[[pin]]\npoint = [0.0, 3.1, 0.0]\n"
    (tube_rig_dir / "pins.toml").write_text(text)
    rig = load_rig(tube_rig_dir / "pins.toml")
    top = int(np.argmax(rig.V[:, 1] - np.abs(rig.V[:, 0]) - np.abs(rig.V[:, 2])))
    assert rig.pattern().positional == (0, top)
    np.testing.assert_allclose(rig.V[top], [0, 3, 0])
