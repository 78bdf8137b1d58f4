"""Per-pattern factorisation of the FAST global step (the "refactor" cost).

Fixed rows A0 T = b (c0 x 4m, the same for x, y, z): 4 unit rows per full handle, the row
M_v per positional vertex (sum_k b_k M_{v_k} per positional surface point), and the pivot
row [p 1](T_child - T_parent) = 0 per relative joint.
With N a basis of null(A0) and H = N (N^T Q N)^{-1} N^T, the minimiser of
tr(T^T Q T) - 2 tr(T^T K Rt) subject to A0 T = b is
    T = H K Rt + (I - H Q) A0^+ b = G Rt + P2 b.
The relative rows (child linear part = parent linear part @ R, R per frame) are added per frame
by a Schur complement on H in the native solver. A pattern whose reduced Hessian N^T Q N is
singular (free global translation, a handle with no influence, ...) is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from puppet.fast.errors import PatternError
from puppet.fast.pattern import Pattern, positional_corners

CONDITION_LIMIT = 1e8
"""Largest accepted condition number of the reduced Hessian N^T Q N (and of the relative Schur).
The per-frame solve runs in float32, so rounding is amplified by up to this factor in the
worst-determined direction."""


@dataclass
class Factor:
    """Per-pattern matrices (float64). G: (4m, 3r); P2: (4m, 4kf + kp); H: (4m, 4m)."""

    G: np.ndarray
    P2: np.ndarray
    H: np.ndarray


def constraint_rows(pattern: Pattern, V: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """A0 (4kf + kp + kr, 4m): full rows, positional rows, then pivot rows."""
    m = weights.shape[1]
    kf, kp, kr = len(pattern.full), len(pattern.positional), len(pattern.relative)
    A = np.zeros((4 * kf + kp + kr, 4 * m))
    for q, j in enumerate(pattern.full):
        A[4 * q : 4 * q + 4, 4 * j : 4 * j + 4] = np.eye(4)
    A[4 * kf : 4 * kf + kp] = positional_rows(pattern.positional, V, weights)
    for q, (c, p, pivot) in enumerate(pattern.relative):
        ph = np.append(np.asarray(pivot, np.float64), 1.0)
        A[4 * kf + kp + q, 4 * c : 4 * c + 4] += ph
        A[4 * kf + kp + q, 4 * p : 4 * p + 4] -= ph
    return A


def positional_rows(entries, V: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(k, 4m) float64: the LBS row of each ``Pattern.positional`` entry, row @ T being its deformed
    position: M_v = weights[v] (x) [V_v 1] (entry 4j + i: weights[v, j] [V_v 1]_i) for a vertex v,
    sum_c b_c M_{v_c} for a surface point ((v0, v1, v2), (b0, b1, b2)).
    V: (n, 3) rest positions; weights: (n, m) float64."""
    corners, bary = positional_corners(entries)
    Vh = np.concatenate([V[corners], np.ones(corners.shape + (1,))], axis=2)  # (k, 3, 4)
    rows = np.einsum("kc,kcj,kci->kji", bary, weights[corners], Vh)
    return rows.reshape(len(corners), 4 * weights.shape[1])


def contact_rows(pattern: Pattern, V: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(kc, 4m) float64: the LBS row M_v of each contact vertex (row M_v T[:, c] = target_c)."""
    rows = [(weights[v][:, None] * np.append(V[v], 1.0)[None, :]).ravel() for v, _ in pattern.contacts]
    return np.array(rows, np.float64).reshape(len(rows), 4 * weights.shape[1])


def _describe_null(vec: np.ndarray, m: int) -> str:
    blocks = vec.reshape(m, 4)
    mag = np.linalg.norm(blocks, axis=1)
    handles = np.flatnonzero(mag > 0.1 * mag.max()).tolist()
    linear = np.linalg.norm(blocks[:, :3])
    if linear < 1e-6 * np.linalg.norm(blocks) and len(handles) == m:
        return "the global translation is free: fix one handle fully or pin a vertex (positional)"
    return f"handles {handles} can move without changing the energy: constrain them or one of their neighbours"


def factor(pattern: Pattern, V: np.ndarray, weights: np.ndarray, Q: np.ndarray, K: np.ndarray) -> Factor:
    """Factor the global step for a pattern; raise PatternError if the solve is undetermined."""
    m = weights.shape[1]
    n4 = 4 * m
    A = constraint_rows(pattern, V, weights)
    nvals = 4 * len(pattern.full) + len(pattern.positional)
    c = A.shape[0]
    if c:
        U, s, Vt = np.linalg.svd(A, full_matrices=True)
        rank = int((s > s[0] * 1e-9).sum())
        if rank < c:
            raise PatternError(
                f"pattern: {c - rank} of its {c} constraint rows are redundant (e.g. a vertex pinned inside a "
                "fully constrained handle, or a relative pivot between two full handles); remove them"
            )
        N = Vt[rank:].T
        pinv = Vt[:rank].T @ (U[:, :rank].T / s[:rank, None])
    else:
        N = np.eye(n4)
        pinv = np.zeros((n4, 0))
    if N.shape[1] == 0:
        H = np.zeros((n4, n4))
    else:
        Hr = N.T @ Q @ N
        Hr = 0.5 * (Hr + Hr.T)
        # Cholesky of the Jacobi-scaled Hessian plus LAPACK's condition estimate: the scaling makes
        # the test independent of model units (linear and translation rows differ by a length^2).
        # The eigen-decomposition only runs to explain a refusal.
        dg = np.diag(Hr)
        ok = bool((dg > 0).all())
        if ok:
            d = np.sqrt(dg)
            Hs = Hr / d[:, None] / d[None, :]
            try:
                chol = scipy.linalg.cho_factor(Hs, check_finite=False)
                rcond, info = scipy.linalg.lapack.dpocon(chol[0], np.abs(Hs).sum(0).max(), uplo="L" if chol[1] else "U")
                ok = info == 0 and rcond > 1.0 / CONDITION_LIMIT
            except np.linalg.LinAlgError:
                ok = False
        if not ok:
            lam, vecs = np.linalg.eigh(Hr)
            raise PatternError(
                f"pattern leaves the solve undetermined (reduced Hessian singular or scaled condition > "
                f"{CONDITION_LIMIT:.0e}): " + _describe_null(N @ vecs[:, 0], m)
            )
        H = N @ (scipy.linalg.cho_solve(chol, N.T / d[:, None], check_finite=False) / d[:, None])
        H = 0.5 * (H + H.T)
    if pattern.relative or pattern.contacts:
        _check_relative(pattern, H, contact_rows(pattern, V, weights))
    P2 = pinv[:, :nvals] - H @ (Q @ pinv[:, :nvals])
    G = H @ K
    return Factor(G=G, P2=P2, H=H)


def _check_relative(pattern: Pattern, H: np.ndarray, contacts: np.ndarray) -> None:
    """The relative rows (at R = I) and, per column, that column's contact rows must be independent
    on the fixed rows' null space."""
    n4 = H.shape[0]
    kr = len(pattern.relative)
    AR = np.zeros((3 * kr, n4))
    for q, (c, p, _) in enumerate(pattern.relative):
        for i in range(3):
            AR[3 * q + i, 4 * c + i] = 1.0
            AR[3 * q + i, 4 * p + i] = -1.0
    axes = pattern.contact_axes()
    for col in range(3 if pattern.contacts else 1):
        rows = np.flatnonzero(axes[:, col]) if pattern.contacts else np.zeros(0, int)
        A = np.vstack([AR, contacts[rows]])
        if A.shape[0] == 0:
            continue
        S = A @ H @ A.T
        lam, vecs = np.linalg.eigh(0.5 * (S + S.T))
        if lam[0] > max(lam[-1], 1e-300) / CONDITION_LIMIT:
            continue
        worst = int(np.argmax(np.abs(vecs[:, 0])))
        if worst >= 3 * kr:
            q = int(rows[worst - 3 * kr])
            v, ax = pattern.contacts[q]
            raise PatternError(
                f"pattern.contacts[{q}] (vertex {v}, axes {ax!r}): the contact and the other constraints "
                "over-determine the handles (e.g. a vertex whose handles are all fixed, or pinned twice); remove it"
            )
        q = worst // 3
        c, p, _ = pattern.relative[q]
        raise PatternError(
            f"pattern.relative[{q}] (child {c}, parent {p}): the relative rows and the other constraints "
            "over-determine the handles (e.g. both handles full, a relative cycle, or a pinned vertex whose "
            "handles are all fixed through the chain); remove one"
        )
