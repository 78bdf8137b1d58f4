"""The native FAST iteration against an independent plain NumPy/SciPy implementation, and the
reduced energy against the full-space ARAP energy evaluated from libigl's cotangent weights.

Nothing here imports puppet.fast internals: the reference builds its own LBS matrix, energy
matrices (from igl.cotmatrix_entries) and KKT system from the model's inputs (V, F, weights,
cluster labels)."""

import igl
import numpy as np
import pytest
import scipy.linalg

from puppet.fast import FastModel, Pattern


def lbs(V, W):
    n, m = W.shape
    Vh = np.hstack([V, np.ones((n, 1))])
    return np.einsum("ij,ic->ijc", W, Vh).reshape(n, 4 * m)


def spokes_and_rims_terms(V, F):
    """(a, b, w, set) for spokes-and-rims: every triangle edge, in the set of each of its 3 corners."""
    C = igl.cotmatrix_entries(V, F)  # half cotangents; column c: edge opposite corner c
    a = F[:, [1, 2, 0]]
    b = F[:, [2, 0, 1]]
    A, B, Wt, S = [], [], [], []
    for corner in range(3):
        A.append(a.ravel())
        B.append(b.ravel())
        Wt.append(C.ravel())
        S.append(np.repeat(F[:, corner], 3))
    return np.concatenate(A), np.concatenate(B), np.concatenate(Wt), np.concatenate(S)


def polar(C):
    U, _, Vt = np.linalg.svd(C)
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., 2] *= d[..., None]
    return U @ Vt


class Reference:
    """Plain local/global FAST in float64: dense KKT with every constraint row."""

    def __init__(self, V, F, W, labels):
        self.V, self.W, self.labels = V, W, labels
        self.m = W.shape[1]
        self.r = labels.max() + 1
        self.M = lbs(V, W)
        a, b, w, s = spokes_and_rims_terms(V, F)
        self.a, self.b, self.w, self.g = a, b, w, labels[s]
        D = self.M[a] - self.M[b]  # (terms, 4m)
        self.Q = (D * w[:, None]).T @ D
        e = V[a] - V[b]
        self.K = np.zeros((4 * self.m, 3 * self.r))
        for i in range(3):
            np.add.at(self.K.T, 3 * self.g + i, (D * (w * e[:, i])[:, None]))
        self.c0 = float((w * (e * e).sum(1)).sum())

    def rotations(self, T):
        S = (self.K.T @ T).reshape(self.r, 3, 3)  # S_g = D_g^T T, C_g = S_g^T
        return polar(S.transpose(0, 2, 1))

    def energy(self, T):
        R = self.rotations(T)
        C = (self.K.T @ T).reshape(self.r, 3, 3).transpose(0, 2, 1)
        return float(np.trace(T.T @ self.Q @ T) - 2 * np.einsum("gij,gij->", R, C) + self.c0)

    def rows(self, pattern, values):
        n4 = 4 * self.m
        A, B = [], []
        for q, j in enumerate(pattern.full):
            for c in range(4):
                row = np.zeros(n4)
                row[4 * j + c] = 1
                A.append(row)
                B.append(values.full[q, c])
        for q, v in enumerate(pattern.positional):
            A.append(self.M[v])
            B.append(values.positional[q])
        for q, (c, p, piv) in enumerate(pattern.relative):
            ph = np.append(piv, 1.0)
            row = np.zeros(n4)
            row[4 * c : 4 * c + 4] = ph
            row[4 * p : 4 * p + 4] = -ph
            A.append(row)
            B.append(np.zeros(3))
            R = values.relative[q].astype(np.float64)
            for i in range(3):  # child rows = R^T parent rows
                row = np.zeros(n4)
                row[4 * c + i] = 1
                row[4 * p : 4 * p + 3] = -R[:, i]
                A.append(row)
                B.append(np.zeros(3))
        return np.array(A), np.array(B)

    def iterate(self, pattern, values, T, iterations):
        A, B = self.rows(pattern, values)
        n4, c = 4 * self.m, A.shape[0]
        KKT = np.block([[2 * self.Q, A.T], [A, np.zeros((c, c))]])
        lu = scipy.linalg.lu_factor(KKT)
        T = T.astype(np.float64)
        for _ in range(iterations):
            Rt = self.rotations(T).transpose(0, 2, 1).reshape(3 * self.r, 3)
            rhs = np.vstack([2 * self.K @ Rt, B])
            T = scipy.linalg.lu_solve(lu, rhs)[:n4]
        return T


def mixed_pattern_values(model, helpers):
    V = model.V
    tip = int(np.argmax(V[:, 0]))
    pattern = Pattern(full=(0,), relative=((1, 0, (4.0 / 3, 0.0, 0.0)),), positional=(tip,))
    values = pattern.values()
    values.full[0] = model.rest_T()[0:4]
    values.relative[0] = helpers.rot_z(0.5).astype(np.float32)
    values.positional[0] = (V[tip] + np.array([-0.6, 1.2, 0.3])).astype(np.float32)
    return pattern, values


def test_native_iteration_matches_numpy_reference(bar_model, helpers):
    model = bar_model
    ref = Reference(model.V, model.F, model.weights.astype(np.float64), model.labels)
    pattern, values = mixed_pattern_values(model, helpers)
    solver = model.solver(pattern)
    T = model.rest_T()
    T_ref = T.astype(np.float64)
    scale = np.abs(T_ref).max()
    for chunk in (1, 2, 3):  # also exercises warm starts across calls
        solver.solve(values, T, iterations=chunk, accelerate=False)
        T_ref = ref.iterate(pattern, values, T_ref, chunk)
        np.testing.assert_allclose(T, T_ref, atol=1e-4 * scale, rtol=0)
    assert abs(solver.stats.energy - ref.energy(T_ref)) <= 1e-4 * ref.c0


def energy_terms(V, F, labels, energy):
    """(a, b, w, cluster) of every term of the full-space energy, from libigl's cotangents."""
    C = igl.cotmatrix_entries(V, F)
    a = F[:, [1, 2, 0]]
    b = F[:, [2, 0, 1]]
    if energy == "spokes_and_rims":
        return [(a.ravel(), b.ravel(), C.ravel(), np.repeat(labels[F[:, s]], 3)) for s in range(3)]
    if energy == "spokes":
        return [(a.ravel(), b.ravel(), C.ravel(), labels[end.ravel()]) for end in (a, b)]
    L = labels[F]
    mode = np.where((L[:, 0] == L[:, 1]) | (L[:, 0] == L[:, 2]), L[:, 0], np.where(L[:, 1] == L[:, 2], L[:, 1], L[:, 0]))
    return [(a.ravel(), b.ravel(), C.ravel(), np.repeat(mode, 3))]


def full_space_energy(V, Vd, F, labels, energy="spokes_and_rims"):
    """sum over edge sets of w |e' - R_g e|^2 with one optimal rotation per cluster."""
    r = labels.max() + 1
    cov = np.zeros((r, 3, 3))
    terms = energy_terms(V, F, labels, energy)
    for a, b, w, g in terms:
        e = V[a] - V[b]
        ed = Vd[a] - Vd[b]
        np.add.at(cov, g, w[:, None, None] * ed[:, :, None] * e[:, None, :])
    R = polar(cov)
    E = 0.0
    for a, b, w, g in terms:
        e = V[a] - V[b]
        ed = Vd[a] - Vd[b]
        res = ed - np.einsum("kij,kj->ki", R[g], e)
        E += float((w * (res * res).sum(1)).sum())
    return E


@pytest.mark.parametrize("energy", ["spokes_and_rims", "spokes", "elements"])
def test_full_space_energy_decreases_and_matches_reduced(bar, helpers, energy):
    V, F, W = bar
    model = FastModel(V, F, W, clusters=16, extra_weights=2, energy=energy, cache_dir=False)
    pattern, values = mixed_pattern_values(model, helpers)
    solver = model.solver(pattern)
    T = model.rest_T()
    Wd = model.weights.astype(np.float64)
    Vh = np.hstack([model.V, np.ones((model.n, 1))])
    energies = []
    for _ in range(8):
        stats = solver.solve(values, T, iterations=1, accelerate=False)
        Vd = np.einsum("ij,ic,jcd->id", Wd, Vh, T.astype(np.float64).reshape(model.m, 4, 3))
        E = full_space_energy(model.V, Vd, model.F, model.labels, energy)
        # float32 T and matrices: the energy is exact to ~1e-7 of the rest-edge scale c0.
        assert abs(E - stats.energy) <= 1e-4 * E + 2e-6 * model.c0
        energies.append(E)
    assert energies[0] > 0.0
    assert all(b <= a * (1 + 1e-5) for a, b in zip(energies, energies[1:]))
    assert energies[-1] < energies[0]
