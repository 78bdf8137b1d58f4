"""ARAP energy types and their reduced matrices in the skinning subspace.

An energy is a sum over *edge terms* (a, b, w, k): rest edge e_ab = v_a - v_b with cotangent
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

from puppet.fast.energy_names import ENERGIES
from puppet.fast.errors import MeshError

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


MULTIPLICITY = {"spokes": 2.0, "spokes_and_rims": 3.0, "elements": 1.0}
"""How many edge sets each element edge belongs to, per energy type (spokes: both endpoints'
sets; spokes and rims: the sets of the triangle's 3 corners; elements: its own element's)."""


def element_edges(V: np.ndarray, F: np.ndarray, area_eps: float):
    """Edges of the kept elements: (a, b, w) with shape (k, e) each (e = 3 for triangles, 6 for
    tets), the kept element list F (k, 3|4), the corner of a and b in each element, and the
    number of dropped degenerate elements."""
    if F.shape[1] == 3:
        C, keep = triangle_cot_weights(V, F, area_eps)
        ca, cb = np.array([1, 2, 0]), np.array([2, 0, 1])  # edge opposite corner c
    else:
        C, keep = tet_cot_weights(V, F, area_eps)
        ca, cb = _TET_EDGES[:, 0], _TET_EDGES[:, 1]
    Fk = F[keep]
    return Fk[:, ca], Fk[:, cb], C[keep], Fk, ca, cb, int((~keep).sum())


def element_clusters(labels: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Cluster of each element: the most common label of its corners (the first on ties)."""
    L = labels[F]
    best = L[:, 0].copy()
    best_count = (L == L[:, :1]).sum(1)
    for c in range(1, L.shape[1]):
        cnt = (L == L[:, c : c + 1]).sum(1)
        better = cnt > best_count
        best = np.where(better, L[:, c], best)
        best_count = np.maximum(best_count, cnt)
    return best


def lbs_matrix(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(n, 4m) float64 LBS matrix M: M[i, 4j+c] = W[i, j] * [v_i 1]_c."""
    n, m = W.shape
    Vh = np.hstack([V, np.ones((n, 1))])
    return (W[:, :, None] * Vh[:, None, :]).reshape(n, 4 * m)


def _scatter_entries(F, tv, g, count):
    """COO entries of E for per-element corner vectors tv (k, corners, 3) placed in cluster g (k,)
    with weight count (k,)."""
    k, nc, _ = tv.shape
    rows = np.repeat(F.reshape(-1), 3)
    cols = (3 * np.repeat(g, nc * 3)) + np.tile(np.arange(3), k * nc)
    data = (tv * count[:, None, None]).reshape(-1)
    return rows, cols, data


def reduced_matrices(V, F, W, labels, r, energy, area_eps):
    """Q (4m, 4m), K (4m, 3r), c0 and the count of dropped degenerate elements (see module doc)."""
    if energy not in ENERGIES:
        raise MeshError(f"energy: {energy!r} is not one of {ENERGIES}")
    if F.shape[1] == 4 and energy == "spokes_and_rims":
        raise MeshError("energy: 'spokes_and_rims' needs triangles; use 'spokes' or 'elements' with tets")
    n = V.shape[0]
    a, b, w, Fk, ca, cb, dropped = element_edges(V, F, area_eps)
    if Fk.shape[0] == 0:
        raise MeshError("F: every element is degenerate (zero area or volume)")
    mult = MULTIPLICITY[energy]
    e = V[a] - V[b]  # (k, edges, 3)
    we = w[..., None] * e
    c0 = mult * float((we * e).sum())
    # L = mult * sum_edges w (d_a - d_b)(d_a - d_b)^T
    af, bf, wf = a.ravel(), b.ravel(), mult * w.ravel()
    L = sp.coo_matrix(
        (np.concatenate([wf, wf, -wf, -wf]), (np.concatenate([af, bf, af, bf]), np.concatenate([af, bf, bf, af]))),
        shape=(n, n),
    ).tocsr()
    M = lbs_matrix(V, W)
    Q = M.T @ (L @ M)
    Q = 0.5 * (Q + Q.T)
    # E (n, 3r): E[a, 3g+i] += w e_i, E[b, 3g+i] -= w e_i for every term (edge, set with cluster g).
    k, ne = w.shape
    nc = Fk.shape[1]
    if energy == "spokes":
        # Edge (a, b) is a spoke of a (cluster g_a) and of b (g_b): rows a and b receive +-w e in
        # both clusters. Entries landing in the row's own cluster are summed per vertex; only
        # edges crossing clusters add entries in a neighbour's cluster.
        ga, gb = labels[af], labels[bf]
        wv = we.reshape(-1, 3)
        own_w = np.where(ga == gb, 2.0, 1.0)[:, None] * wv
        own = np.zeros((n, 3))
        for i in range(3):
            own[:, i] = np.bincount(af, own_w[:, i], n) - np.bincount(bf, own_w[:, i], n)
        cross = ga != gb
        xa, xb, xw = af[cross], bf[cross], wv[cross]
        rows = np.concatenate([np.repeat(np.arange(n), 3), np.repeat(xb, 3), np.repeat(xa, 3)])
        cols = np.concatenate(
            [
                (3 * np.repeat(labels, 3)) + np.tile(np.arange(3), n),
                (3 * np.repeat(ga[cross], 3)) + np.tile(np.arange(3), xa.size),
                (3 * np.repeat(gb[cross], 3)) + np.tile(np.arange(3), xa.size),
            ]
        )
        parts = [(rows, cols, np.concatenate([own.ravel(), -xw.ravel(), xw.ravel()]))]
    else:
        # Per element: the vector each corner receives from the element's edges.
        tv = np.zeros((k, nc, 3))
        for j in range(ne):
            tv[np.arange(k), ca[j]] += we[:, j]
            tv[np.arange(k), cb[j]] -= we[:, j]
        if energy == "elements":
            parts = [_scatter_entries(Fk, tv, element_clusters(labels, Fk), np.ones(k))]
        else:
            # Each corner's set holds all edges: weight cluster g by how many corners lie in g.
            G = labels[Fk]  # (k, 3)
            parts = []
            for s in range(nc):
                first = np.ones(k, bool)
                for t in range(s):
                    first &= G[:, t] != G[:, s]
                cnt = (G == G[:, s : s + 1]).sum(1).astype(float)
                if first.any():
                    parts.append(_scatter_entries(Fk[first], tv[first], G[first, s], cnt[first]))
    rows = np.concatenate([p[0] for p in parts])
    cols = np.concatenate([p[1] for p in parts])
    data = np.concatenate([p[2] for p in parts])
    E = sp.csr_matrix((data, (rows, cols)), shape=(n, 3 * r))
    K = np.ascontiguousarray(np.asarray(E.T @ M).T)
    return Q, K, c0, dropped
