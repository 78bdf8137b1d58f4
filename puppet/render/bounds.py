"""A box sure to hold every skinned vertex, from the handle transforms alone (no read-back).

Vertices are grouped by place (clusters of rest positions). For vertex i of cluster g with
centroid c_g, and o_gj = [c_g 1] T_j (the centroid moved by handle j):
    v'_i = sum_j w_ij (v_i - c_g) A_j  +  p_g  +  sum_j (w_ij - wbar_gj) (o_gj - p_g)  +  s_i p_g
with p_g = sum_j wbar_gj o_gj (wbar: the cluster's mean weights) and s_i = sum_j (w_ij - wbar_gj).
So |v'_i - p_g| <= sum_j E_gj |A_j| + sum_j D_gj |o_gj - p_g| + S_g |p_g| componentwise, with
E_gj = max_i |w_ij| |v_i - c_g|, D_gj = max_i |w_ij - wbar_gj|, S_g = max_i |s_i|: exact
arithmetic on any weights (negative, not summing to one) and any affine T. Near a joint the
handles move the centroid alike, so the box stays close to the skinned mesh's own.
"""

import numpy as np

from puppet.render.clusters import cluster_labels

#: Clusters of the bound: more is tighter (on the critter, 128: a box 1.2-1.3x the skinned
#: mesh's volume in strong poses, about 60 us a frame; 64: 1.4-1.9x), each costs a few floats
#: per handle per frame.
BOUND_CLUSTERS = 128


class SkinnedBounds:
    """Box of the vertices V (n, 3) skinned with weights W (n, m) by any T (4m, 3).

    box(T) returns a (2, 3) float32 array [min, max] that the next call overwrites; it holds
    every skinned vertex (up to float32 rounding), at a cost of a few small matrix products.
    """

    def __init__(self, V: np.ndarray, W: np.ndarray, clusters: int = BOUND_CLUSTERS):
        V = np.asarray(V, dtype=np.float64)
        W = np.asarray(W, dtype=np.float64)
        labels = cluster_labels(V, clusters)
        k, m = int(labels.max()) + 1, W.shape[1]
        centers = np.zeros((k, 3))
        E = np.zeros((k, m, 3))
        mean_w = np.zeros((k, m))
        D = np.zeros((k, m))
        S = np.zeros(k)
        for g in range(k):
            members = labels == g
            Vg, Wg = V[members], W[members]
            centers[g] = Vg.mean(axis=0)
            E[g] = (np.abs(Wg)[:, :, None] * np.abs(Vg - centers[g])[:, None, :]).max(axis=0)
            mean_w[g] = Wg.mean(axis=0)
            D[g] = np.abs(Wg - mean_w[g]).max(axis=0)
            S[g] = np.abs((Wg - mean_w[g]).sum(axis=1)).max()
        self.m = m
        self._centers_h = np.hstack([centers, np.ones((k, 1))]).astype(np.float32)  # (k, 4)
        self._E = E.reshape(k, 3 * m).astype(np.float32)  # rows: (handle, axis)
        self._mean_w = mean_w.astype(np.float32)[:, None, :]  # (k, 1, m)
        self._D = D.astype(np.float32)[:, None, :]
        self._S = S.astype(np.float32)[:, None]
        # Per-frame arrays.
        self._T_by_row = np.zeros((4, m, 3), np.float32)  # T's row r of every handle
        self._abs_A = np.zeros((m, 3, 3), np.float32)
        self._moved = np.zeros((k, m, 3), np.float32)  # o_gj
        self._blend = np.zeros((k, 1, 3), np.float32)  # p_g
        self._spread = np.zeros((k, m, 3), np.float32)
        self._radius = np.zeros((k, 3), np.float32)
        self._term = np.zeros((k, 1, 3), np.float32)
        self._edge = np.zeros((k, 3), np.float32)
        self.box_out = np.zeros((2, 3), np.float32)

    def box(self, T: np.ndarray) -> np.ndarray:
        """(2, 3) float32 [min, max] holding every vertex skinned by T (4m, 3)."""
        blocks = T.reshape(self.m, 4, 3)
        np.copyto(self._T_by_row, blocks.transpose(1, 0, 2))
        k = len(self._moved)
        np.matmul(self._centers_h, self._T_by_row.reshape(4, -1), out=self._moved.reshape(k, -1))
        np.matmul(self._mean_w, self._moved, out=self._blend)
        p = self._blend[:, 0]
        np.abs(blocks[:, :3], out=self._abs_A)
        np.matmul(self._E, self._abs_A.reshape(-1, 3), out=self._radius)
        np.subtract(self._moved, self._blend, out=self._spread)
        np.abs(self._spread, out=self._spread)
        np.matmul(self._D, self._spread, out=self._term)
        self._radius += self._term[:, 0]
        np.abs(p, out=self._edge)
        self._edge *= self._S
        self._radius += self._edge
        np.subtract(p, self._radius, out=self._edge)
        np.min(self._edge, axis=0, out=self.box_out[0])
        np.add(p, self._radius, out=self._edge)
        np.max(self._edge, axis=0, out=self.box_out[1])
        return self.box_out
