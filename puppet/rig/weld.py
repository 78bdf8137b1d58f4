"""Welding: one vertex for the copies an exporter split at UV or normal seams.

glTF stores one vertex per distinct (position, normal, uv, ...) tuple, so a character exported
from Blender has two or more copies of every vertex along its UV seams. They have the same
position and the same skin weights; left apart they give the renderer a crease (each copy gets
its own normal) and the FAST energy a cut (two surfaces that only happen to touch).

``weld_index`` finds the copies; ``weld_mesh`` builds the welded mesh and keeps, for each file
vertex, its welded index (``Rig.source_index``), so exports can write the file's own order.
"""

from __future__ import annotations

import numpy as np

#: Two positions closer than this fraction of the mesh's bounding-box diagonal are the same.
POSITION_TOLERANCE = 1e-6
#: Two weights closer than this are the same (exporters quantize weights to 1/255 or 1/65535).
WEIGHT_TOLERANCE = 1e-5


def weld_index(positions: np.ndarray, weights: np.ndarray, *,
               position_tolerance: float = POSITION_TOLERANCE,
               weight_tolerance: float = WEIGHT_TOLERANCE) -> np.ndarray:
    """For each vertex, the index of its welded vertex.

    positions: (n, 3) float; weights: (n, m) float (one row per vertex).
    Vertices with the same position (within ``position_tolerance`` times the bounding-box
    diagonal) and the same weights (within ``weight_tolerance``) weld into one. Welded vertices
    are numbered in the order of their first copy in the file, so a file with no copies maps to
    ``arange(n)``. Returns (n,) int64.
    """
    positions = np.asarray(positions, np.float64)
    weights = np.asarray(weights, np.float64)
    n = len(positions)
    if n == 0:
        return np.zeros(0, np.int64)
    extent = float(np.linalg.norm(positions.max(0) - positions.min(0))) or 1.0
    grid = np.round(positions / (position_tolerance * extent)).astype(np.int64)
    _, by_position, counts = np.unique(grid, axis=0, return_inverse=True, return_counts=True)
    by_position = by_position.reshape(-1)
    label = by_position.copy()
    shared = np.flatnonzero(counts[by_position] > 1)
    if len(shared):  # only vertices that share a position are compared by weight
        key = np.concatenate([by_position[shared, None],
                              np.round(weights[shared] / weight_tolerance).astype(np.int64)], axis=1)
        _, sub = np.unique(key, axis=0, return_inverse=True)
        label[shared] = len(counts) + sub.reshape(-1)
    # Renumber labels by first occurrence.
    _, first, inverse = np.unique(label, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return rank[inverse.reshape(-1)]


def weld_mesh(V: np.ndarray, F: np.ndarray, W: np.ndarray, source_index: np.ndarray):
    """(V, F, W) of the welded mesh.

    V: (n, 3), F: (f, 3), W: (n, m) of the file's vertices; source_index: (n,) from
    :func:`weld_index`. Each welded vertex takes its first copy's position and weights;
    triangles that collapse (two corners welded together) or repeat another one with the
    same winding are dropped.
    Returns V (k, 3) float64, F (f', 3) int32, W (k, m) float64.
    """
    source_index = np.asarray(source_index, np.int64)
    k = int(source_index.max()) + 1 if len(source_index) else 0
    first = np.full(k, len(source_index), np.int64)
    np.minimum.at(first, source_index, np.arange(len(source_index)))
    F_welded = source_index[np.asarray(F, np.int64)]
    keep = ((F_welded[:, 0] != F_welded[:, 1]) & (F_welded[:, 1] != F_welded[:, 2])
            & (F_welded[:, 0] != F_welded[:, 2]))
    F_welded = F_welded[keep]
    # A triangle repeated with the same winding (a mesh instanced twice welds onto itself)
    # counts once; each is compared rotated to start at its smallest index.
    start = np.argmin(F_welded, axis=1)[:, None]
    rolled = np.take_along_axis(F_welded, (start + np.arange(3)) % 3, axis=1)
    _, once = np.unique(rolled, axis=0, return_index=True)
    if len(once) < len(F_welded):
        F_welded = F_welded[np.sort(once)]
    return V[first], F_welded.astype(np.int32), W[first]
