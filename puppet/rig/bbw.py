"""Bounded biharmonic weights (Jacobson et al. 2011) with libigl, cached on disk.

Pipeline: check the surface is watertight and the skeleton lies inside it; tetrahedralize the
interior with tetgen conforming to the bones (``igl.copyleft.tetgen.mesh_with_skeleton``:
surface vertices are kept first, bone samples are added); boundary conditions (1 on a bone, 0
on the others); ``igl.bbw`` (active-set QP, bounds [0, 1]); rows normalized to sum to 1.
"""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

import numpy as np

from puppet.cache import Entry, cache_root, code_digest
from puppet.rig.errors import RigError
from puppet.rig.skeleton import Skeleton
from puppet.rig import weight_check
from puppet.rig.weight_check import normalize_weights

CACHE_VERSION = 1


class WeightInputError(RigError):
    """The mesh or skeleton cannot be given automatic weights; ``problems`` lists why."""

    def __init__(self, problems: list[str], path=None) -> None:
        self.problems = list(problems)
        super().__init__("cannot compute bounded biharmonic weights:\n  - " + "\n  - ".join(problems),
                         path=path, field="weights")


def default_cache_dir() -> Path:
    """The cache root (``puppet.cache``: $PUPPET_CACHE, else $XDG_CACHE_HOME/puppet, else
    ~/.cache/puppet)."""
    return cache_root()


def code_version() -> str:
    """A digest of the code that computes the weights: this module, the normalization
    (``weight_check``) and the libigl release. Part of every cache key: edited weights code
    never serves weights computed by the old one."""
    return f"{code_digest(__file__, weight_check.__file__)} libigl {metadata.version('libigl')}"


def check_bbw_input(V: np.ndarray, F: np.ndarray, skeleton: Skeleton) -> list[str]:
    """Problems that make BBW impossible or meaningless: open or non-manifold surface,
    handles outside the surface. Empty list when the input is fine."""
    import igl

    problems = []
    F64 = np.ascontiguousarray(F, np.int64)
    edges = np.sort(np.concatenate([F64[:, [0, 1]], F64[:, [1, 2]], F64[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    open_edges = int((counts == 1).sum())
    if open_edges:
        problems.append(f"mesh is not watertight: {open_edges} boundary edges (close the holes)")
    if (counts > 2).any():
        problems.append(f"mesh is not edge-manifold: {int((counts > 2).sum())} edges shared by 3+ triangles")
    if problems:
        return problems
    points = np.concatenate([skeleton.heads, skeleton.tails, 0.5 * (skeleton.heads + skeleton.tails)])
    winding = igl.fast_winding_number(np.ascontiguousarray(V, np.float64), F64, points)
    b = skeleton.bone_count
    outside = sorted({skeleton.names[i % b] for i in np.flatnonzero(winding < 0.5)})
    if outside:
        problems.append(f"skeleton lies outside the mesh at bones {outside} (winding number < 0.5)")
    return problems


def _handles(skeleton: Skeleton):
    """libigl handle arrays: C (c,3) points, P point-handle indices, BE bone edges, and the
    weight column (libigl orders [P; BE]) of each bone."""
    points: list[np.ndarray] = []

    def point_index(x):
        for i, q in enumerate(points):
            if np.linalg.norm(q - x) < 1e-9:
                return i
        points.append(np.asarray(x, float))
        return len(points) - 1

    P, BE, point_bones, edge_bones = [], [], [], []
    for i in range(skeleton.bone_count):
        h, t = skeleton.heads[i], skeleton.tails[i]
        if np.linalg.norm(t - h) < 1e-9:
            P.append(point_index(h))
            point_bones.append(i)
        else:
            BE.append((point_index(h), point_index(t)))
            edge_bones.append(i)
    column_of_bone = np.empty(skeleton.bone_count, np.int64)
    for col, bone in enumerate(point_bones + edge_bones):
        column_of_bone[bone] = col
    return (np.array(points), np.array(P, np.int64), np.array(BE, np.int64).reshape(-1, 2),
            column_of_bone)


def bbw_tet(V: np.ndarray, F: np.ndarray, skeleton: Skeleton, *, samples_per_bone: int = 10,
            path=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """BBW on a tet mesh of the surface's interior (no cache, no normalization).

    Returns TV (t, 3) tet vertices (the surface's V first), TT (e, 4) tets, and
    W_tet (t, bones) float64 weights in bone order.
    Raises WeightInputError listing every problem with the input.
    """
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    problems = check_bbw_input(V, F, skeleton)
    if problems:
        raise WeightInputError(problems, path=path)
    import igl
    import igl.copyleft.tetgen as tetgen

    C, P, BE, column_of_bone = _handles(skeleton)
    try:
        TV, TT, _ = tetgen.mesh_with_skeleton(V, F, C, P, BE, np.zeros((0, 2), np.int64),
                                              samples_per_bone, "pq2YQ")
    except RuntimeError as err:
        raise WeightInputError([f"tetgen failed to mesh the interior: {err}"], path=path) from err
    if len(TV) < len(V) or np.abs(TV[: len(V)] - V).max() > 1e-9:
        raise WeightInputError(["tetgen did not keep the surface vertices first"], path=path)
    try:
        b, bc = igl.boundary_conditions(TV, TT, C, P, BE, np.zeros((0, 2), np.int64),
                                        np.zeros((0, 3), np.int64))
    except RuntimeError as err:
        raise WeightInputError([f"boundary conditions: {err}"], path=path) from err
    W_tet = igl.bbw(TV, TT, b, bc, partition_unity=True, max_iter=16)
    return TV, TT, W_tet[:, column_of_bone]


def bbw_weights(V: np.ndarray, F: np.ndarray, skeleton: Skeleton, *, cache_dir=None,
                use_cache: bool = True, samples_per_bone: int = 10, path=None) -> np.ndarray:
    """Bounded biharmonic weights of each bone.

    V: (n, 3) float64 surface vertices; F: (f, 3) triangles (closed, outward);
    skeleton: bones (a bone with head == tail is a point handle).
    Returns (n, bones) float64, non-negative, rows summing to 1. Cached under ``cache_dir``
    (default :func:`default_cache_dir`), keyed by the inputs and ``code_version()``.
    Raises WeightInputError listing every problem with the input.
    """
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    entry = None
    if use_cache:
        entry = Entry.keyed(Path(cache_dir or default_cache_dir()), "bbw", ".npy", code_version(),
                            CACHE_VERSION, V, F, np.asarray(skeleton.heads), np.asarray(skeleton.tails),
                            np.asarray(skeleton.parents), int(samples_per_bone))
        shape = (len(V), skeleton.bone_count)

        def read(file):
            W = np.load(file)
            if W.shape != shape:
                raise ValueError(f"shape {W.shape}, expected {shape}")
            return W

        W = entry.load(read)
        if W is not None:
            return W
    TV, _, W_tet = bbw_tet(V, F, skeleton, samples_per_bone=samples_per_bone, path=path)
    W = normalize_weights(W_tet[: len(V)], path=path)
    if entry is not None:  # a folder that refuses is logged; the next run computes them again
        entry.store(lambda tmp: np.save(tmp, W))
    return W


def interpolate_in_tets(TV: np.ndarray, TT: np.ndarray, values: np.ndarray, points: np.ndarray,
                        candidates: int = 16) -> np.ndarray:
    """Barycentric interpolation of per-tet-vertex ``values`` (t, m) at ``points`` (p, 3).

    Each point uses the tet (among the ``candidates`` with nearest centroids) that contains it
    best (largest smallest barycentric coordinate); points outside the tet mesh get their
    barycentrics clipped to the tet and renormalized. Returns (p, m).
    """
    from scipy.spatial import cKDTree

    centroids = TV[TT].mean(axis=1)
    _, near = cKDTree(centroids).query(points, k=min(candidates, len(TT)))
    near = near.reshape(len(points), -1)
    corners = TV[TT[near]]                                   # (p, c, 4, 3)
    edges = corners[:, :, 1:, :] - corners[:, :, :1, :]      # (p, c, 3, 3)
    rhs = points[:, None, :] - corners[:, :, 0, :]           # (p, c, 3)
    try:
        lam = np.linalg.solve(np.swapaxes(edges, -1, -2), rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:
        lam = np.einsum("pcij,pcj->pci", np.linalg.pinv(np.swapaxes(edges, -1, -2)), rhs)
    bary = np.concatenate([1 - lam.sum(axis=-1, keepdims=True), lam], axis=-1)  # (p, c, 4)
    best = bary.min(axis=-1).argmax(axis=1)
    rows = np.arange(len(points))
    b = np.clip(bary[rows, best], 0.0, None)
    b /= b.sum(axis=1, keepdims=True)
    tets = TT[near[rows, best]]                               # (p, 4)
    return np.einsum("pk,pkm->pm", b, values[tets])
