"""PoseFill: a pattern's per-frame values gathered from forward kinematics in one native pass,
against plain NumPy indexing; wrong arrays refused, never copied."""

import numpy as np
import pytest

from puppet.fast import Pattern
from puppet.fast.pattern import PoseFill


def poses(rng, bones):
    """Arbitrary (b, 3, 3) rotations and (b, 3, 4) affines: the gather does not care what they are."""
    return rng.normal(size=(bones, 3, 3)), rng.normal(size=(bones, 3, 4))


def test_fill_writes_full_blocks_and_relative_rotations():
    rng = np.random.default_rng(7)
    rot, pose = poses(rng, 9)
    pattern = Pattern(full=(0, 3, 5), relative=((7, 5, (0.0, 1.0, 0.0)), (2, 0, (0.0, 0.5, 0.0))))
    values = pattern.values()
    PoseFill(pattern).fill(values, rot, pose)
    np.testing.assert_array_equal(values.full, pose[[0, 3, 5]].transpose(0, 2, 1).astype(np.float32))
    np.testing.assert_array_equal(values.relative, rot[[7, 2]].astype(np.float32))


def test_fill_of_a_pattern_without_sensed_bones_writes_nothing():
    rng = np.random.default_rng(8)
    rot, pose = poses(rng, 3)
    pattern = Pattern(positional=(4,))
    values = pattern.values()
    PoseFill(pattern).fill(values, rot, pose)
    assert values.full.shape == (0, 4, 3) and values.relative.shape == (0, 3, 3)


def test_fill_refuses_a_bone_outside_the_poses_and_wrong_dtypes():
    rng = np.random.default_rng(9)
    rot, pose = poses(rng, 3)
    pattern = Pattern(full=(0, 3))
    values = pattern.values()
    with pytest.raises(ValueError, match=r"constraint_values: full_bones\[1\] = 3 is not a bone"):
        PoseFill(pattern).fill(values, rot, pose)
    ok = Pattern(full=(0, 1))
    with pytest.raises(TypeError, match="incompatible function arguments"):
        PoseFill(ok).fill(ok.values(), rot.astype(np.float32), pose)
    with pytest.raises(TypeError, match="incompatible function arguments"):
        PoseFill(ok).fill(ok.values(), rot, np.asfortranarray(pose))
