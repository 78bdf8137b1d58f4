"""The native module is built, bound zero-copy, and its rotation fit is right."""

import numpy as np
import pytest

from puppet import _native


def _random_rotations(rng, count):
    q = rng.normal(size=(count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def _polar_reference(S):
    """Closest proper rotation by numpy's SVD in double precision."""
    U, _, Vt = np.linalg.svd(S.astype(np.float64))
    d = np.sign(np.linalg.det(U @ Vt))
    U[:, :, 2] *= d[:, None]
    return U @ Vt


def test_fit_rotations_matches_svd_reference():
    rng = np.random.default_rng(0)
    S = rng.normal(size=(257, 3, 3)).astype(np.float32)
    R = np.empty_like(S)
    _native.fit_rotations(S, R)
    np.testing.assert_allclose(R, _polar_reference(S), atol=2e-5)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-5)


def test_fit_rotations_recovers_rotations_scaled_by_spd():
    rng = np.random.default_rng(1)
    Q = _random_rotations(rng, 64)
    A = rng.normal(size=(64, 3, 3))
    P = A @ A.transpose(0, 2, 1) + 0.5 * np.eye(3)  # symmetric positive definite
    S = (Q @ P).astype(np.float32)
    R = np.empty_like(S)
    _native.fit_rotations(S, R)
    np.testing.assert_allclose(R, Q, atol=1e-4)


def test_fit_rotations_degenerate_inputs_give_proper_rotations():
    S = np.zeros((4, 3, 3), np.float32)
    S[1] = np.diag([1.0, 1.0, 0.0])  # rank 2
    S[2] = np.diag([1.0, 1.0, -1.0])  # a reflection
    S[3, 0, 0] = np.nan
    R = np.empty_like(S)
    _native.fit_rotations(S, R)
    assert np.isfinite(R).all()
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-5)
    np.testing.assert_allclose(R[0], np.eye(3), atol=1e-6)
    np.testing.assert_allclose(R[1], np.eye(3), atol=1e-5)
    np.testing.assert_allclose(R[3], np.eye(3), atol=1e-6)


def test_fit_rotations_is_scale_invariant():
    rng = np.random.default_rng(2)
    S = rng.normal(size=(16, 3, 3)).astype(np.float32)
    R1, R2 = np.empty_like(S), np.empty_like(S)
    _native.fit_rotations(S * np.float32(1e-12), R1)
    _native.fit_rotations(S, R2)
    np.testing.assert_allclose(R1, R2, atol=1e-5)


def test_fit_rotations_refuses_wrong_dtype_or_layout():
    S = np.zeros((3, 3, 3), np.float64)
    R = np.zeros((3, 3, 3), np.float32)
    with pytest.raises(TypeError):
        _native.fit_rotations(S, R)
    S32 = np.zeros((3, 3, 3), np.float32)
    with pytest.raises(TypeError):
        _native.fit_rotations(S32, np.zeros((3, 3, 6), np.float32)[:, :, ::2])


def test_fit_rotations_refuses_mismatched_counts():
    with pytest.raises(ValueError, match="fit_rotations"):
        _native.fit_rotations(np.zeros((3, 3, 3), np.float32), np.zeros((2, 3, 3), np.float32))


def test_stubs_ship_with_the_module():
    from pathlib import Path

    stub = Path(_native.__file__).with_name("_native.pyi")
    assert "def fit_rotations" in stub.read_text()


def test_kinematics_stubs_ship_with_their_module():
    from pathlib import Path

    from puppet import _kinematics

    stub = Path(_kinematics.__file__).with_name("_kinematics.pyi")
    assert all(f"def {name}" in stub.read_text()
               for name in ("joint_rotations", "pose_from_rotations", "forward_kinematics", "constraint_values"))
