"""BVH export: parsed back by an independent parser; Euler angles rebuild the rotations."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from puppet.export import BvhWriter, ExportError, euler_to_matrix, matrix_to_euler, write_bvh
from puppet.export.euler import ORDERS

_spec = importlib.util.spec_from_file_location("export_bvh_readers", Path(__file__).with_name("readers.py"))
readers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readers)
read_bvh = readers.read_bvh

NAMES = ["hips", "spine", "neck", "head", "arm_l", "hand_l", "arm_r", "leg"]
PARENTS = [-1, 0, 1, 2, 1, 4, 1, 0]
OFFSETS = np.array([[0, 1, 0], [0, 0.3, 0], [0, 0.4, 0], [0, 0.1, 0.02], [0.2, 0.35, 0],
                    [0.3, 0, 0], [-0.2, 0.35, 0], [0.1, -0.5, 0]], dtype=float)


def random_rotations(n_frames, b, seed=0):
    R = Rotation.random(n_frames * b, random_state=seed).as_matrix().reshape(n_frames, b, 3, 3)
    R[0, 2] = euler_to_matrix(np.array([0.4, np.pi / 2, -0.2]), "ZXY")  # gimbal lock
    R[1, 3] = np.eye(3)
    return R


@pytest.mark.parametrize("order", ["ZXY", "XYZ", "ZYX"])
def test_bvh_roundtrip(tmp_path, order):
    path = tmp_path / "skeleton.bvh"
    R = random_rotations(25, len(NAMES))
    roots = np.cumsum(np.full((25, 3), 0.01), axis=0)
    n = write_bvh(path, names=NAMES, parents=PARENTS, offsets=OFFSETS, frames=R,
                  frame_time=1 / 60, order=order, root_positions=roots)
    assert n == 25
    bvh = read_bvh(path.read_text())
    ends, values = bvh.end_sites, bvh.motion
    assert bvh.frame_time == pytest.approx(1 / 60, abs=1e-9)
    assert values.shape == (25, 3 + 3 * len(NAMES))
    assert sorted(bvh.names) == sorted(NAMES)
    for i, name in enumerate(NAMES):
        k = bvh.names.index(name)
        parent = bvh.parents[k]
        assert (None if parent < 0 else bvh.names[parent]) == (None if PARENTS[i] < 0 else NAMES[PARENTS[i]])
        np.testing.assert_allclose(bvh.offsets[k], OFFSETS[i], atol=1e-6)
        rot = [f"{a}rotation" for a in order]
        assert bvh.channels[k] == (["Xposition", "Yposition", "Zposition"] + rot if i == 0 else rot)
    assert sorted(ends) == sorted(["head", "hand_l", "arm_r", "leg"])
    np.testing.assert_allclose(ends["head"], OFFSETS[3], atol=1e-6)
    np.testing.assert_allclose(values[:, :3], roots, atol=1e-6)
    # Rotations rebuilt from the file's Euler angles (scipy, intrinsic = BVH order) match.
    col = 3
    for name in bvh.names:
        j = NAMES.index(name)
        deg = values[:, col : col + 3]
        rebuilt = Rotation.from_euler(order, deg, degrees=True).as_matrix()
        np.testing.assert_allclose(rebuilt, R[:, j], atol=1e-5)
        col += 3
    assert col == values.shape[1]


def test_euler_curves_are_continuous(tmp_path):
    """A joint turning steadily past 180 degrees gives an unwrapped curve, not a jump."""
    path = tmp_path / "spin.bvh"
    b = len(NAMES)
    angles = np.linspace(0, 4 * np.pi, 50)
    R = np.tile(np.eye(3), (50, b, 1, 1))
    R[:, 1] = euler_to_matrix(np.stack([angles, 0 * angles, 0 * angles], -1), "ZXY")
    write_bvh(path, names=NAMES, parents=PARENTS, offsets=OFFSETS, frames=R, frame_time=0.04)
    bvh = read_bvh(path.read_text())
    values = bvh.motion
    col = 3 + 3 * bvh.names.index("spine")
    np.testing.assert_allclose(values[:, col], np.degrees(angles), atol=1e-4)


def test_euler_input_and_default_root(tmp_path):
    path = tmp_path / "euler.bvh"
    deg = np.zeros((3, len(NAMES), 3))
    deg[:, 4] = [[10, 20, 30], [-10, 0, 5], [370, 1, 2]]
    with BvhWriter(path, names=NAMES, parents=PARENTS, offsets=OFFSETS, frame_time=0.5) as w:
        for d in deg:
            w.write(d)
    bvh = read_bvh(path.read_text())
    values = bvh.motion
    np.testing.assert_allclose(values[:, :3], np.tile(OFFSETS[0], (3, 1)))
    col = 3 + 3 * bvh.names.index("arm_l")
    np.testing.assert_allclose(values[:, col : col + 3], deg[:, 4])


@pytest.mark.parametrize("order", ORDERS)
def test_matrix_to_euler_against_scipy(order):
    R = Rotation.random(500, random_state=7).as_matrix()
    e = matrix_to_euler(R, order)
    np.testing.assert_allclose(Rotation.from_euler(order, e).as_matrix(), R, atol=1e-12)
    np.testing.assert_allclose(euler_to_matrix(e, order), R, atol=1e-12)
    assert np.all(np.abs(e[:, 1]) <= np.pi / 2 + 1e-12)
    lock = euler_to_matrix(np.array([[0.3, np.pi / 2, 0.7], [-1.0, -np.pi / 2, 2.0]]), order)
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(lock, order), order), lock,
                               atol=1e-12)


def test_bad_skeletons_and_frames(tmp_path):
    p = tmp_path / "bad.bvh"
    ok = dict(names=NAMES, parents=PARENTS, offsets=OFFSETS, frame_time=0.1)
    cases = [
        (dict(names=["a", "b c"] + NAMES[2:]), "joint 1 name 'b c'"),
        (dict(names=["a", "a"] + NAMES[2:]), r"duplicate joint names \['a'\]"),
        (dict(parents=[-1, -1] + PARENTS[2:]), r"one root \(parent -1\), got joints \[0, 1\]"),
        (dict(parents=[-1, 2, 1] + PARENTS[3:]), "not connected to the root"),
        (dict(parents=[-1, 9] + PARENTS[2:]), "joint 'spine' has bad parent 9"),
        (dict(offsets=OFFSETS[:3]), r"offsets must be finite \(8, 3\)"),
        (dict(frame_time=0.0), "frame_time must be > 0"),
        (dict(order="ABC"), "Euler order must be one of"),
    ]
    for change, message in cases:
        with pytest.raises(ExportError, match=message) as e:
            BvhWriter(p, **{**ok, **change})
        assert str(p) in str(e.value)
    R = np.tile(np.eye(3), (len(NAMES), 1, 1))
    R[5] *= 1.5
    with BvhWriter(p, **ok) as w:
        w.write(np.tile(np.eye(3), (len(NAMES), 1, 1)))
        with pytest.raises(ExportError, match="frame 1, joint 'hand_l': not a rotation matrix"):
            w.write(R)
        R[5] = np.diag([1.0, 1.0, -1.0])
        with pytest.raises(ExportError, match="hand_l.*det -1"):
            w.write(R)
        with pytest.raises(ExportError, match=r"frame 1: rotations have shape \(8, 3, 3, 1\)"):
            w.write(R[..., None])
    assert read_bvh(p.read_text()).motion.shape == (1, 27)  # the good frame is kept
