"""Per-axis positional constraints (contacts): the native solve against an independent float64
NumPy/SciPy local/global solve of the same equations (one KKT system per column)."""

import numpy as np
import pytest
import scipy.linalg

from puppet.fast import Pattern, PatternError
from puppet.fast.factor import constraint_rows, contact_rows


def reference_solve(model, pattern, values, iterations=1500):
    """float64 local/global iterations from the rest pose: R_g = polar(S_g^T) with S = K^T T, then
    per column c: min T_c^T Q T_c - 2 T_c^T (K Rt)_c subject to the fixed rows, the relative rows
    at this frame's R and the contact rows naming column c (dense KKT solve)."""
    V, Wt, K, Q = model.V, model.weights64, model.K, model.Q
    m, r = model.m, model.r
    A0 = constraint_rows(pattern, V, Wt)
    nb = 4 * len(pattern.full) + len(pattern.positional)
    b0 = np.vstack([values.full.reshape(-1, 3), values.positional]).astype(np.float64)
    b0 = np.vstack([b0, np.zeros((A0.shape[0] - nb, 3))])  # pivot rows: right side 0
    AR = np.zeros((3 * len(pattern.relative), 4 * m))
    for q, (c, p, _) in enumerate(pattern.relative):
        R = values.relative[q].astype(np.float64)
        for i in range(3):
            AR[3 * q + i, 4 * c + i] = 1.0
            for k in range(3):
                AR[3 * q + i, 4 * p + k] -= R[k, i]
    C = contact_rows(pattern, V, Wt)
    axes = pattern.contact_axes()
    kkt = []
    for col in range(3):
        rows = np.flatnonzero(axes[:, col])
        A = np.vstack([A0, AR, C[rows]])
        b = np.concatenate([b0[:, col], np.zeros(AR.shape[0]), values.contact[rows, col].astype(np.float64)])
        KKT = np.block([[2.0 * Q, A.T], [A, np.zeros((A.shape[0], A.shape[0]))]])
        kkt.append((scipy.linalg.lu_factor(KKT), b))
    T = model.rest_T().astype(np.float64)
    for _ in range(iterations):
        S = (K.T @ T).reshape(r, 3, 3).transpose(0, 2, 1)  # S_g^T
        U, _, Vt = np.linalg.svd(S)
        U[:, :, 2] *= np.sign(np.linalg.det(U @ Vt))[:, None]
        Rt = (U @ Vt).transpose(0, 2, 1).reshape(3 * r, 3)
        rhs = 2.0 * K @ Rt
        for col, (lu, b) in enumerate(kkt):
            T[:, col] = scipy.linalg.lu_solve(lu, np.concatenate([rhs[:, col], b]))[: 4 * m]
    return T


def diag(model):
    return float(np.linalg.norm(model.V.max(0) - model.V.min(0)))


@pytest.mark.parametrize("relative", [False, True])
def test_contacts_match_a_float64_reference(bar_model, helpers, relative):
    model = bar_model
    V = model.V
    tip = int(np.argmax(V[:, 0] - 0.01 * V[:, 1]))  # the far end, lowest ring vertex
    mid = int(np.argmin(np.abs(V[:, 0] - 2.7) + np.abs(V[:, 2] + 0.5)))
    rel = ((1, 0, (4.0 / 3, 0.0, 0.0)),) if relative else ()
    pattern = Pattern(full=(0,), relative=rel, contacts=((tip, "y"), (mid, "xz")))
    values = pattern.values()
    values.full[0] = model.rest_T()[:4]
    values.full[0, :3] = helpers.rot_z(-0.4).T  # the root tilts the bar down ...
    if relative:
        values.relative[0] = helpers.rot_z(0.3)
    values.contact[0, 1] = V[tip, 1] + 0.8  # ... and the tip rests on a floor above it
    values.contact[1] = (V[mid, 0] - 0.2, 123.0, V[mid, 2] + 0.3)  # y is free: 123 is never read
    solver = model.solver(pattern)
    T = model.rest_T()
    solver.solve(values, T, iterations=1500, accelerate=False)
    ref = reference_solve(model, pattern, values)
    Vd, Vr = model.deform(T), model.deform(ref)
    # The contact holds in its axes only; the others are free (not at their rest or target values).
    assert abs(Vd[tip, 1] - values.contact[0, 1]) <= 1e-5 * diag(model)
    assert abs(Vd[mid, 0] - values.contact[1, 0]) <= 1e-5 * diag(model)
    assert abs(Vd[mid, 2] - values.contact[1, 2]) <= 1e-5 * diag(model)
    assert abs(Vd[mid, 1] - 123.0) > 100.0
    assert np.abs(Vd - Vr).max() <= 1e-4 * diag(model)
    # Giving every axis the y-column's constraints (what an isotropic solver does) is far off.
    iso = Pattern(full=(0,), relative=rel, contacts=((tip, "xyz"), (mid, "xz")))
    iso_values = iso.values()
    iso_values.full[:], iso_values.relative[:] = values.full, values.relative
    iso_values.contact[0] = Vd[tip]
    iso_values.contact[0, 0] = V[tip, 0]
    iso_values.contact[1] = values.contact[1]
    T_iso = model.rest_T()
    model.solver(iso).solve(iso_values, T_iso, iterations=300)
    assert np.abs(model.deform(T_iso) - Vr).max() > 1e-2 * diag(model)


def test_contacts_with_acceleration_and_warm_start(bar_model, helpers):
    model = bar_model
    V = model.V
    tip = int(np.argmax(V[:, 0]))
    pattern = Pattern(full=(0,), contacts=((tip, "y"),))
    solver = model.solver(pattern)
    values = pattern.values()
    values.full[0] = model.rest_T()[:4]
    T = model.rest_T()
    for f in range(10):
        values.contact[0, 1] = V[tip, 1] + 0.1 * f
        solver.solve(values, T, iterations=20, accelerate=True)
        assert abs(model.deform(T)[tip, 1] - values.contact[0, 1]) <= 1e-5 * diag(model)


def test_contact_errors(bar_model):
    model = bar_model
    with pytest.raises(PatternError, match="vertex 999999 is not in"):
        model.solver(Pattern(full=(0,), contacts=((999999, "y"),)))
    with pytest.raises(PatternError, match="axes 'yw'"):
        model.solver(Pattern(full=(0,), contacts=((3, "yw"),)))
    # A vertex whose only handle is fully given cannot also take a contact.
    v = int(np.argmax(model.weights[:, 0]))
    with pytest.raises(PatternError, match=r"pattern.contacts\[0\]"):
        model.solver(Pattern(full=tuple(range(model.m)), contacts=((v, "y"),)))
