"""Vertices grouped by place: k-means on rest positions (the contact shadow's spheres, the
character's screen bounds)."""

import numpy as np


def kmeans(points: np.ndarray, k: int, iterations: int) -> np.ndarray:
    """Cluster labels (n,) of points (n, 3): farthest-point seeds, then Lloyd iterations."""
    centers = [points[0]]
    dist = np.sum((points - points[0]) ** 2, axis=1)
    for _ in range(1, k):
        centers.append(points[int(np.argmax(dist))])
        dist = np.minimum(dist, np.sum((points - centers[-1]) ** 2, axis=1))
    centers = np.array(centers)
    labels = np.zeros(len(points), dtype=np.int64)
    for _ in range(iterations):
        d2 = (points**2).sum(1)[:, None] - 2 * points @ centers.T + (centers**2).sum(1)[None, :]
        labels = np.argmin(d2, axis=1)
        sums = np.stack([np.bincount(labels, weights=points[:, j], minlength=k) for j in range(3)], 1)
        counts = np.bincount(labels, minlength=k)
        filled = counts > 0
        centers[filled] = sums[filled] / counts[filled, None]
    return labels


def cluster_labels(V: np.ndarray, count: int, iterations: int = 8) -> np.ndarray:
    """Labels (n,) in [0, c) of V (n, 3), c <= count clusters, none empty: k-means on a
    subsample (for speed on big meshes), then every vertex assigned to its nearest center."""
    V = np.asarray(V, dtype=np.float64)
    k = int(min(count, len(V)))
    step = max(1, len(V) // 8000)
    labels_sub = kmeans(V[::step], k, iterations)
    seeds = np.array([V[::step][labels_sub == c].mean(axis=0) for c in range(k) if np.any(labels_sub == c)])
    d2 = (V**2).sum(1)[:, None] - 2 * V @ seeds.T + (seeds**2).sum(1)[None, :]
    labels = np.argmin(d2, axis=1)
    _, labels = np.unique(labels, return_inverse=True)  # drop clusters no vertex is nearest to
    return labels.reshape(-1)
