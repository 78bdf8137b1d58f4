"""Key reduction (puppet/export/key_reduction.py): curves a few LINEAR keys reproduce exactly are
reduced to those keys; every reduced curve stays within the tolerance at every frame under the
glTF spec's slerp and Blender's per-component lerp + normalize, both computed here independently."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from puppet.export.key_reduction import curve_error, reduce_curve, rotation_angle_deg

TIMES = np.arange(1, 121) / 30.0  # 120 frames at 30 fps, frame k at k/30 s


def hemisphere(q):
    """(N, 4) quaternions, each on the hemisphere of the one before (as the writer keeps them)."""
    q = np.array(q, float)
    for i in range(1, len(q)):
        if q[i] @ q[i - 1] < 0:
            q[i] = -q[i]
    return q


def slerp_read(times, keys, values):
    """The glTF spec's LINEAR rotation sampler, by scipy's Slerp (not the module's code)."""
    return Slerp(times[keys], Rotation.from_quat(values[keys]))(times).as_quat()


def nlerp_read(times, keys, values):
    """Blender's importer: one LINEAR F-curve per component (numpy.interp), then normalized."""
    q = np.stack([np.interp(times, times[keys], values[keys, c]) for c in range(4)], 1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def angle_deg(p, q):
    """(N,) degrees of the rotation between p and q (scipy)."""
    return np.degrees((Rotation.from_quat(p).inv() * Rotation.from_quat(q)).magnitude())


def test_a_polyline_keeps_exactly_its_corners():
    corners = [0, 30, 31, 75, 119]
    heights = np.array([[0, 0, 0], [1.5, 0, -2], [1.5, 0.2, -2], [0.3, 0.9, 0], [0.3, 0.9, 4]], float)
    frames = np.arange(120)
    values = np.stack([np.interp(frames, corners, heights[:, c]) for c in range(3)], 1)
    keys = reduce_curve(TIMES, values, "translation", 1e-6)
    assert keys.tolist() == corners
    assert curve_error(TIMES, values, keys, "translation").max() < 1e-9


def test_a_steady_turn_needs_two_keys_and_a_still_channel_too():
    angles = np.radians(np.linspace(0.0, 20.0, 120))
    axis = np.array([0.3, 0.8, -0.52]) / np.linalg.norm([0.3, 0.8, -0.52])
    q = Rotation.from_rotvec(np.outer(angles, axis)).as_quat()
    assert reduce_curve(TIMES, hemisphere(q), "rotation", 0.1).tolist() == [0, 119]
    still = np.tile([0.0, 0.0, 0.0, 1.0], (120, 1))
    assert reduce_curve(TIMES, still, "rotation", 0.1).tolist() == [0, 119]


@pytest.mark.parametrize("tol", [0.05, 0.5, 2.0])
def test_every_frame_stays_within_the_tolerance_for_both_readers(tol):
    rng = np.random.default_rng(4)
    t = np.arange(120) / 30.0
    rotvec = np.stack([0.9 * np.sin(1.7 * t + 0.3), 0.5 * np.sin(3.1 * t),
                       1.2 * np.sin(0.8 * t + 1.0)], 1)
    rotvec += rng.normal(0.0, 0.002, rotvec.shape)  # a solve's small wobble
    values = hemisphere(Rotation.from_rotvec(rotvec).as_quat())
    keys = reduce_curve(TIMES, values, "rotation", tol)
    assert keys[0] == 0 and keys[-1] == 119 and (np.diff(keys) > 0).all()
    assert len(keys) < 120
    for read in (slerp_read, nlerp_read):
        assert angle_deg(read(TIMES, keys, values), values).max() <= tol + 1e-6
    assert curve_error(TIMES, values, keys, "rotation").max() <= tol
    # The module's angle agrees with scipy's.
    np.testing.assert_allclose(rotation_angle_deg(values[:-1], values[1:]),
                               angle_deg(values[:-1], values[1:]), atol=1e-6)


def test_a_fast_turn_is_kept_for_blender_too():
    """A 160° turn in 10 frames: slerp alone would need two keys; Blender's nlerp strays up to
    several degrees between them, so more keys are kept."""
    angles = np.radians(np.linspace(0.0, 160.0, 11))
    values = hemisphere(Rotation.from_rotvec(np.outer(angles, [0, 0, 1])).as_quat())
    times = TIMES[:11]
    keys = reduce_curve(times, values, "rotation", 0.5)
    assert len(keys) > 2
    assert angle_deg(nlerp_read(times, keys, values), values).max() <= 0.5 + 1e-6
    assert angle_deg(nlerp_read(times, np.array([0, 10]), values), values).max() > 0.5


def test_forced_frames_are_keys_and_the_rest_stays_within_the_tolerance():
    """A shot's key poses are forced keys: a steady turn that two keys would reproduce keeps
    them too, and no segment crosses one."""
    angles = np.radians(np.linspace(0.0, 20.0, 120))
    values = hemisphere(Rotation.from_rotvec(np.outer(angles, [0, 0, 1])).as_quat())
    keys = reduce_curve(TIMES, values, "rotation", 0.1, forced=[47, 12, 47, 90])
    assert keys.tolist() == [0, 12, 47, 90, 119]
    rotvec = np.stack([np.sin(np.arange(120) / 9.0), np.zeros(120), np.zeros(120)], 1)
    wavy = hemisphere(Rotation.from_rotvec(rotvec).as_quat())
    keys = reduce_curve(TIMES, wavy, "rotation", 0.5, forced=[12, 47, 90])
    assert {0, 12, 47, 90, 119} <= set(keys.tolist()) and len(keys) < 120
    assert curve_error(TIMES, wavy, keys, "rotation").max() <= 0.5


def test_a_forced_frame_outside_the_curve_is_refused():
    with pytest.raises(ValueError, match=r"forced frames must be within 0\.\.119, got 3\.\.120"):
        reduce_curve(TIMES, np.zeros((120, 3)), "translation", 0.1, forced=[3, 120])
