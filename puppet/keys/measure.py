"""How good in-betweens are: the rig's ARAP energy of a deformed mesh, and a closed mesh's volume.

Used by bench/keys.py and the tests to compare FAST in-betweens with the baseline of a per-vertex
linear blend of the two key meshes (which shrinks a turning limb).
"""

from __future__ import annotations

import numpy as np

from puppet.export.joint_transforms import polar_rotations
from puppet.fast.energy import element_clusters, element_edges


def arap_energy(model, deformed: np.ndarray) -> float:
    """The rig's ARAP energy of ``deformed`` in the full space, one optimal rotation per cluster.

    model: a ``puppet.fast.FastModel`` (rest V, elements F, its energy type and cluster labels).
    deformed: (n, 3) float64 deformed vertices, model units. Returns
    sum over terms w |e'_ab − R_g e_ab|² (``puppet.fast.energy``'s terms, squared model units).
    """
    V, F, labels = model.V, model.F if model.tets is None else model.tets, model.labels
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    eps = 1e-12 * diag ** (2 if F.shape[1] == 3 else 3)
    a, b, w, Fk, ca, cb, _ = element_edges(V, F, eps)
    if model.energy == "spokes_and_rims":
        sets = [labels[Fk[:, c]][:, None].repeat(a.shape[1], 1) for c in range(Fk.shape[1])]
    elif model.energy == "spokes":
        sets = [labels[a], labels[b]]
    else:
        sets = [element_clusters(labels, Fk)[:, None].repeat(a.shape[1], 1)]
    e = (V[a] - V[b]).reshape(-1, 3)
    d = (np.asarray(deformed, np.float64)[a] - np.asarray(deformed, np.float64)[b]).reshape(-1, 3)
    w = w.reshape(-1)
    cov = np.zeros((model.r, 3, 3))
    for g in sets:
        np.add.at(cov, g.reshape(-1), w[:, None, None] * d[:, :, None] * e[:, None, :])
    R = polar_rotations(cov)
    energy = 0.0
    for g in sets:
        res = d - np.einsum("kij,kj->ki", R[g.reshape(-1)], e)
        energy += float((w * (res * res).sum(1)).sum())
    return energy


def volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume of a closed triangle mesh (vertices (n, 3), faces (f, 3), outward
    winding), cubic model units."""
    p = np.asarray(vertices, np.float64)[faces]
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)
