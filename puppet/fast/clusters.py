"""Rotation clusters: k-means in weight space (farthest-point seeding, then Lloyd iterations).

Vertices with similar skinning weights move alike, so they share one ARAP rotation. Seeding and
Lloyd iterations run on a fixed random subsample (at most ``sample`` rows) for speed; every vertex
is then assigned to its nearest centre. Clusters left empty are dropped and the labels compacted
(documented repair), so the number of clusters returned may be below the number asked for.
"""

from __future__ import annotations

import numpy as np


def _sqdist(X: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(len(X), len(C)) squared distances, float32 GEMM."""
    return (X * X).sum(1)[:, None] - 2.0 * (X @ C.T) + (C * C).sum(1)[None, :]


def kmeans_weight_space(W: np.ndarray, r: int, *, lloyd: int = 10, sample: int = 8000, seed: int = 0) -> np.ndarray:
    """(n,) int32 cluster labels in 0..r'-1 (r' <= r) for weight rows W (n, m)."""
    n = W.shape[0]
    r = int(min(r, n))
    X = np.ascontiguousarray(W, dtype=np.float32)
    if n > sample:
        idx = np.sort(np.random.default_rng(seed).choice(n, sample, replace=False))
        Xs = X[idx]
    else:
        Xs = X
    # Farthest-point seeding (first seed: the largest |w|^2, as libigl's partition).
    sq = (Xs * Xs).sum(1)
    first = int(np.argmax(sq))
    centres = np.empty((r, X.shape[1]), np.float32)
    centres[0] = Xs[first]
    d = ((Xs - Xs[first]) ** 2).sum(1)
    for k in range(1, r):
        i = int(np.argmax(d))
        centres[k] = Xs[i]
        d = np.minimum(d, ((Xs - Xs[i]) ** 2).sum(1))
    # Lloyd on the sample.
    labels = None
    for _ in range(lloyd):
        new = np.argmin(_sqdist(Xs, centres), axis=1)
        if labels is not None and np.array_equal(new, labels):
            break
        labels = new
        counts = np.bincount(labels, minlength=r)
        sums = np.zeros_like(centres)
        np.add.at(sums, labels, Xs)
        keep = counts > 0
        centres[keep] = sums[keep] / counts[keep, None]
    full = np.argmin(_sqdist(X, centres), axis=1)
    used, compact = np.unique(full, return_inverse=True)
    return compact.astype(np.int32)
