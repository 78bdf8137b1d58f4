"""ServoUnits.angles (the native conversion, puppet._kinematics.servo_angles) gives exactly what
the NumPy formulas of puppet.servo_models give, for every wrap and clamp case, one reading or
many, and follows a calibration that writes new zeros in place."""

from __future__ import annotations

import numpy as np
import pytest

from puppet import _kinematics
from puppet.servo_models import ServoUnits


def numpy_angles(u: ServoUnits, ticks, clamp=True):
    """The conversion written in NumPy (the formulas of the module docstring)."""
    x = (np.asarray(ticks, float) - u.zero) * u.radians_per_tick
    top = u._top
    wrapped = top - np.remainder(top - x, 2.0 * np.pi)
    x = np.where(u._wrap, wrapped, x)
    return np.clip(x, u.lo, u.hi) if clamp else x


def units():
    # sign, gear, zero, limits: wrapped (span <= 2 pi), unwrapped (span > 2 pi), unlimited-like wide span
    return ServoUnits([1, -1, 1, -1, 1], [1.0, 1.0, 2.0, 0.5, 1.5], [2048, 1000, -5000, 3000, 100_000],
                      [(-np.pi, np.pi), (-1.0, 2.0), (-0.8, 0.8), (-2.5, 1.0), (-10.0, 10.0)],
                      [4096, 4096, 4096, 4096, 1_003_846])


@pytest.mark.parametrize("clamp", [True, False])
def test_native_angles_equal_the_numpy_formulas(clamp):
    u = units()
    rng = np.random.default_rng(3)
    ticks = rng.integers(-3 * 4096 * 4, 3 * 4096 * 4, size=(400, 5)).astype(np.int32)
    ticks[:, 4] = rng.integers(-3_000_000, 3_000_000, size=400)
    many = u.angles(ticks, clamp=clamp)
    np.testing.assert_array_equal(many, numpy_angles(u, ticks, clamp))
    out = np.empty(5)
    for row in ticks[:50]:  # one reading, into a caller's array (the per-frame path)
        assert u.angles(row, out=out, clamp=clamp) is out
        np.testing.assert_array_equal(out, numpy_angles(u, row, clamp))
    # Exactly on a wrap boundary and float ticks.
    edge = u.zero + np.round(np.pi / np.abs(u.radians_per_tick)).astype(np.int64)
    np.testing.assert_array_equal(u.angles(edge, clamp=clamp), numpy_angles(u, edge, clamp))
    np.testing.assert_array_equal(u.angles(ticks[0] + 0.25, clamp=clamp), numpy_angles(u, ticks[0] + 0.25, clamp))


def test_native_angles_follow_zeros_written_in_place():
    u = units()
    ticks = np.array([2100, 900, -4000, 3100, 100_500], np.int32)
    before = u.angles(ticks).copy()
    u.zero[:] = u.zero + 50  # what a calibration does
    after = u.angles(ticks)
    np.testing.assert_array_equal(after, numpy_angles(u, ticks))
    assert not np.array_equal(before, after)


def test_native_angles_refuse_wrong_shapes():
    u = units()
    with pytest.raises(ValueError, match="servo_angles: ticks must be"):
        _kinematics.servo_angles(np.zeros(4), u.zero, u._table, np.zeros(4), True)
    with pytest.raises(ValueError, match="out must have the shape of ticks"):
        _kinematics.servo_angles(np.zeros(5), u.zero, u._table, np.zeros(6), True)
    with pytest.raises(TypeError):
        _kinematics.servo_angles(np.zeros(5, np.float32), u.zero, u._table, np.zeros(5), True)


def test_units_still_pickle_for_batch_workers():
    import pickle

    u = units()
    ticks = np.array([2100, 900, -4000, 3100, 100_500], np.int32)
    u.angles(ticks)  # the native conversion loaded
    copy = pickle.loads(pickle.dumps(u))
    np.testing.assert_array_equal(copy.angles(ticks), u.angles(ticks))
