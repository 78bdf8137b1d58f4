"""ARAP energy types and their reduced matrices in the skinning subspace.

An energy is a list of *edge terms* (a, b, w, k): rest edge e_ab = v_a - v_b with cotangent
weight w in edge set k. Each edge set gets the rotation of its cluster; the energy is
    E = sum_terms w |(v'_a - v'_b) - R_k e_ab|^2.
Edge sets per type (as libigl's ARAPEnergyType):
    spokes:          one set per vertex: its incident edges (weights summed over triangles);
    spokes_and_rims: one set per vertex: every edge of every incident triangle;
    elements:        one set per triangle or tet: its edges.

With V' = M T (M: (n, 4m), M[i, 4j:4j+4] = W[i, j] [v_i 1]) and clusters g, the reduced energy is
    E(T, R) = tr(T^T Q T) - 2 tr(T^T K Rt) + c0
    Q  = M^T L M                        (4m, 4m), L = sum_terms w (d_a - d_b)(d_a - d_b)^T
    K  = M^T E                          (4m, 3r), E[a, 3g+i] += w e_ab,i, E[b, 3g+i] -= w e_ab,i
    Rt = [R_1^T; ...; R_r^T]            (3r, 3)
    c0 = sum_terms w |e_ab|^2
and the local step is S = K^T T (3r, 3): S_g^T = sum w e'_ab e_ab^T, R_g = polar(S_g^T).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from puppet.fast.errors import MeshError

ENERGIES = ("spokes", "spokes_and_rims", "elements")
"""Energy types, as data: each maps to an edge-set construction below."""

# Edges of a tet (corner pairs) in the order of libigl's cotmatrix_entries.
_TET_EDGES = np.array([[1, 2], [2, 0], [0, 1], [3, 0], [3, 1], [3, 2]])


def triangle_cot_weights(V: np.ndarray, F: np.ndarray, area_eps: float) -> tuple[np.ndarray, np.ndarray]:
    """Half cotangents (f, 3) of the angle at each corner (weight of the opposite edge), and a mask
    of triangles kept (area above area_eps); dropped triangles get zero weights."""
    p0, p1, p2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cross = np.cross(p1 - p0, p2 - p0)
    dbl_area = np.linalg.norm(cross, axis=1)
    keep = dbl_area > 2.0 * area_eps
    safe = np.where(keep, dbl_area, 1.0)
    C = np.empty((F.shape[0], 3))
    for c, (a, b, o) in enumerate(((p1, p2, p0), (p2, p0, p1), (p0, p1, p2))):
        C[:, c] = np.einsum("ij,ij->i", a - o, b - o) / safe * 0.5
    C[~keep] = 0.0
    return C, keep


def tet_cot_weights(V: np.ndarray, T: np.ndarray, vol_eps: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, 6) cotangent weights of each tet edge (libigl's cotmatrix_entries, sign so that a
    regular tet has positive weights), and the mask of tets kept (volume above vol_eps)."""
    import igl

    a, b, c, d = (V[T[:, k]] for k in range(4))
    vol = np.abs(np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)) / 6.0
    keep = vol > vol_eps
    C = np.zeros((T.shape[0], 6))
    if keep.any():
        C[keep] = igl.cotmatrix_entries(np.ascontiguousarray(V, np.float64), np.ascontiguousarray(T[keep], np.int64))
    return C, keep


def edge_terms(V: np.ndarray, F: np.ndarray, energy: str, area_eps: float):
    """(a, b, w, set) arrays of edge terms and the number of dropped degenerate elements.

    For elements the set is the element index; otherwise the owning vertex."""
    if energy not in ENERGIES:
        raise MeshError(f"energy: {energy!r} is not one of {ENERGIES}")
    simplex = F.shape[1]
    if simplex == 3:
        C, keep = triangle_cot_weights(V, F, area_eps)
        # Half-edge opposite corner c: (F[:, c+1], F[:, c+2]).
        a = np.stack([F[:, 1], F[:, 2], F[:, 0]], 1)
        b = np.stack([F[:, 2], F[:, 0], F[:, 1]], 1)
    else:
        if energy == "spokes_and_rims":
            raise MeshError("energy: 'spokes_and_rims' needs triangles; use 'spokes' or 'elements' with tets")
        C, keep = tet_cot_weights(V, F, area_eps)
        a = F[:, _TET_EDGES[:, 0]]
        b = F[:, _TET_EDGES[:, 1]]
    F, C, a, b = F[keep], C[keep], a[keep], b[keep]
    elem = np.flatnonzero(keep)
    ne = C.shape[1]
    if energy == "elements":
        sets = np.repeat(elem[:, None], ne, 1)
        return a.ravel(), b.ravel(), C.ravel(), sets.ravel(), int((~keep).sum())
    if energy == "spokes":
        # Each edge is a spoke of both its endpoints.
        return (
            np.concatenate([a.ravel(), a.ravel()]),
            np.concatenate([b.ravel(), b.ravel()]),
            np.concatenate([C.ravel(), C.ravel()]),
            np.concatenate([a.ravel(), b.ravel()]),
            int((~keep).sum()),
        )
    # spokes_and_rims: every edge of a triangle belongs to each of the triangle's 3 corners' sets.
    k = simplex
    return (
        np.tile(a.ravel(), k),
        np.tile(b.ravel(), k),
        np.tile(C.ravel(), k),
        np.concatenate([np.repeat(F[:, s], ne) for s in range(k)]),
        int((~keep).sum()),
    )


def set_clusters(labels: np.ndarray, F: np.ndarray, energy: str, keep_sets: np.ndarray) -> np.ndarray:
    """Cluster of each edge set: the vertex's label, or the most common corner label of an element."""
    if energy != "elements":
        return labels[keep_sets]
    L = labels[F[keep_sets]]  # (k, corners)
    Ls = np.sort(L, axis=1)
    # Mode of each row: the value with the longest run in the sorted row (first on ties).
    best = Ls[:, 0].copy()
    best_count = np.ones(len(Ls), int)
    run = np.ones(len(Ls), int)
    for c in range(1, Ls.shape[1]):
        run = np.where(Ls[:, c] == Ls[:, c - 1], run + 1, 1)
        better = run > best_count
        best = np.where(better, Ls[:, c], best)
        best_count = np.maximum(best_count, run)
    return best


def lbs_matrix(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(n, 4m) float64 LBS matrix M: M[i, 4j+c] = W[i, j] * [v_i 1]_c."""
    n, m = W.shape
    Vh = np.hstack([V, np.ones((n, 1))])
    return (W[:, :, None] * Vh[:, None, :]).reshape(n, 4 * m)


def reduced_matrices(V, F, W, labels, r, energy, area_eps):
    """Q (4m, 4m), K (4m, 3r), c0 and the count of dropped degenerate elements."""
    n = V.shape[0]
    a, b, w, sets, dropped = edge_terms(V, F, energy, area_eps)
    if w.size == 0:
        raise MeshError("F: every element is degenerate (zero area or volume)")
    if energy == "elements":
        g = set_clusters(labels, F, energy, np.arange(F.shape[0]))[sets]
    else:
        g = labels[sets]
    e = V[a] - V[b]  # (terms, 3)
    c0 = float(np.einsum("i,ij,ij->", w, e, e))
    # L = sum w (d_a - d_b)(d_a - d_b)^T.
    L = sp.coo_matrix(
        (np.concatenate([w, w, -w, -w]), (np.concatenate([a, b, a, b]), np.concatenate([a, b, b, a]))), shape=(n, n)
    ).tocsr()
    M = lbs_matrix(V, W)
    LM = L @ M
    Q = M.T @ LM
    Q = 0.5 * (Q + Q.T)
    we = w[:, None] * e
    cols = 3 * g[:, None] + np.arange(3)[None, :]
    E = sp.coo_matrix(
        (
            np.concatenate([we.ravel(), -we.ravel()]),
            (np.concatenate([np.repeat(a, 3), np.repeat(b, 3)]), np.concatenate([cols.ravel(), cols.ravel()])),
        ),
        shape=(n, 3 * r),
    ).tocsr()
    K = np.ascontiguousarray(np.asarray(E.T @ M).T)
    return Q, K, c0, dropped
