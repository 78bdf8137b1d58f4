"""Contact shadow: the character as a few spheres that occlude the ground plane.

Vertices are grouped into clusters (k-means on rest positions); each cluster becomes a sphere
whose center is the exact mean of its skinned vertices, linear in T:
center_c = Q[c] @ T with Q[c, 4j:4j+4] = mean over i in c of w_ij [v_i 1]. The ground shader
sums the spheres' cosine-weighted occlusion, so feet near the floor get a dark, tight contact
shadow and the body a soft one, for any pose and any number of handles.
"""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ShadowSpheres:
    """Q: (k, 4m) float32 (centers = Q @ T, (k, 3)); radii: (k,) float32 [scene units]."""

    Q: np.ndarray
    radii: np.ndarray


def _kmeans(points: np.ndarray, k: int, iterations: int) -> np.ndarray:
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


def shadow_spheres(V: np.ndarray, W: np.ndarray, count: int = 24, iterations: int = 8) -> ShadowSpheres:
    """Spheres for V (n, 3) rest positions and W (n, m) weights; count: at most this many."""
    V = np.asarray(V, dtype=np.float64)
    W = np.asarray(W, dtype=np.float64)
    k = int(min(count, len(V)))
    # Cluster a subsample for speed on big meshes; every vertex is then assigned to a cluster.
    step = max(1, len(V) // 8000)
    labels_sub = _kmeans(V[::step], k, iterations)
    seeds = np.array([V[::step][labels_sub == c].mean(axis=0) for c in range(k) if np.any(labels_sub == c)])
    d2 = (V**2).sum(1)[:, None] - 2 * V @ seeds.T + (seeds**2).sum(1)[None, :]
    labels = np.argmin(d2, axis=1)
    Vh = np.concatenate([V, np.ones((len(V), 1))], axis=1)
    Q, radii = [], []
    for c in range(len(seeds)):
        members = labels == c
        if not np.any(members):
            continue
        size = members.sum()
        Q.append((W[members].T @ Vh[members] / size).reshape(-1))  # (m, 4) flattened as T's rows
        center = V[members].mean(axis=0)
        radii.append(np.sqrt(np.mean(np.sum((V[members] - center) ** 2, axis=1))))
    return ShadowSpheres(Q=np.array(Q, dtype=np.float32), radii=np.array(radii, dtype=np.float32))
