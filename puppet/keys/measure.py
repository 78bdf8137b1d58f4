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


def compare_inbetweens(rig, frames, key_frames) -> dict:
    """FAST in-betweens of a shot against the per-vertex linear blend of the two key meshes.

    rig: the shot's rig (calibrated as the shot). frames: its ``Playback`` at the shot's fps
    with joint rotations (``Playback.of_take(..., rig=rig)``). key_frames: (K,) 0-based frame of
    each key. Every frame is solved through ``Pipeline.solve`` (the one solve path); for every
    in-between f of keys a < f < b, the blend is ``(1 − s) V_a + s V_b``, s = (f − a) / (b − a).
    Returns {"inbetweens": count, "fast"/"blend": {"energy_mean": the rig's ARAP energy
    (``arap_energy``) averaged over the in-betweens, "volume_change_mean"/"volume_change_max":
    |V(f) / V(rest) − 1| of the closed mesh}, "free_bones_moving": the fraction of in-betweens
    in which a free bone's transform changed from the frame before}.
    """
    from puppet.loop import Pipeline

    meshes, moving = [], []
    free = [rig.skeleton.index(name) for name in rig.bone_kinds()["free"]]
    with Pipeline(rig, render=False) as pipeline:
        m = pipeline.T.shape[0] // 4
        before = pipeline.T.copy()
        for f, reading in enumerate(frames):
            pipeline.solve(reading)
            meshes.append(pipeline.deformed())
            T = pipeline.T.reshape(m, 4, 3)
            moving.append(bool(free) and float(np.abs(T[free] - before.reshape(m, 4, 3)[free]).max()) > 0)
            before[...] = pipeline.T
        model = pipeline.model
    rest = volume(rig.V, rig.F)
    sums = {"fast": ([], []), "blend": ([], [])}
    inside = []
    for a, b in zip(key_frames[:-1], key_frames[1:]):
        for f in range(a + 1, b):
            s = (f - a) / (b - a)
            inside.append(f)
            for name, mesh in (("fast", meshes[f]), ("blend", (1 - s) * meshes[a] + s * meshes[b])):
                sums[name][0].append(arap_energy(model, mesh))
                sums[name][1].append(abs(volume(mesh, rig.F) / rest - 1.0))
    report = {"inbetweens": len(inside)}
    for name, (energy, change) in sums.items():
        report[name] = {"energy_mean": float(np.mean(energy)) if energy else 0.0,
                        "volume_change_mean": float(np.mean(change)) if change else 0.0,
                        "volume_change_max": float(np.max(change)) if change else 0.0}
    report["free_bones_moving"] = (float(np.mean([moving[f] for f in inside])) if inside else 0.0)
    return report
