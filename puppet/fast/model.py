"""FastModel: per-rig FAST precompute (LBS matrix, extra weights, clusters, reduced matrices).

    model = FastModel(V, F, W, clusters=50, extra_weights=0, energy="spokes_and_rims")
    solver = model.solver(pattern)            # per pattern (refactor)
    T = model.rest_T()
    solver.solve(values, T, iterations=10)    # per frame, T updated in place

Shapes: V (n, 3) model units; F (f, 3) triangles or tets (t, 4) vertex indices; W (n, m_bones)
bone weights (non-negative, rows summing to one). m = m_bones + extra_weights handles.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from puppet.cache import Entry, cache_dir, code_digest
from puppet.fast.blas import one_blas_thread
from puppet.fast.clusters import kmeans_weight_space
from puppet.fast.energy import ENERGIES, lbs_matrix, reduced_matrices
from puppet.fast.errors import FastError, MeshError
from puppet.fast.pattern import Pattern
from puppet.fast.probes import probe_rows, tolerance_scales
from puppet.fast.solver import Dynamics, Solver
from puppet.fast.weights import full_weights, validate_weights

CACHE_VERSION = "fast-precompute-2"


def default_cache_dir() -> Path:
    """The precompute cache: ``fast`` under the cache root (``puppet.cache``: $PUPPET_CACHE)."""
    return cache_dir("fast")


def code_version() -> str:
    """A digest of the code that produces a precompute: the sources of ``puppet.fast`` and the
    native module. Part of every cache key: an edited solver never reuses stale matrices."""
    from puppet import _native

    return code_digest(str(Path(__file__).parent), _native.__file__)


def _read_precompute(path: Path) -> tuple:
    """A stored precompute -> FastModel._set's arguments (weights, labels, Q, K, c0, dropped)."""
    with np.load(path) as z:
        return z["weights"], z["labels"], z["Q"], z["K"], float(z["c0"]), int(z["dropped"])


def _validate_mesh(V, F, tets):
    V = np.asarray(V)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] < 3:
        raise MeshError(f"V: shape {V.shape}, expected (n, 3) with n >= 3")
    if not np.issubdtype(V.dtype, np.number):
        raise MeshError(f"V: dtype {V.dtype} is not numeric")
    V = V.astype(np.float64)
    if not np.isfinite(V).all():
        rows = np.flatnonzero(~np.isfinite(V).all(1))
        raise MeshError(f"V: rows {rows[:8].tolist()} contain NaN or inf")
    n = V.shape[0]

    def elements(X, name, k):
        X = np.asarray(X)
        if X.ndim != 2 or X.shape[1] != k or X.shape[0] == 0:
            raise MeshError(f"{name}: shape {X.shape}, expected (count, {k})")
        if not np.issubdtype(X.dtype, np.integer):
            raise MeshError(f"{name}: dtype {X.dtype}, expected integer vertex indices")
        if X.min() < 0 or X.max() >= n:
            raise MeshError(f"{name}: indices must be in 0..{n - 1}, got {X.min()}..{X.max()}")
        return X.astype(np.int64)

    F = elements(F, "F", 3)
    T = None if tets is None else elements(tets, "tets", 4)
    return V, F, T


def _order_clusters_by_support(labels: np.ndarray, K: np.ndarray):
    """Renumber clusters so that clusters touched by the same handles are adjacent: the native
    gather then skips whole zero tiles (extra weights have compact support)."""
    m4, r3 = K.shape
    support = np.abs(K).reshape(m4 // 4, 4, r3 // 3, 3).max(axis=(1, 3)) > 0  # (m, r)
    order = np.lexsort(support[::-1])  # sort clusters by their support pattern
    inverse = np.empty_like(order)
    inverse[order] = np.arange(order.size)
    cols = (3 * order[:, None] + np.arange(3)[None, :]).ravel()
    return inverse[labels].astype(np.int32), np.ascontiguousarray(K[:, cols])


class FastModel:
    """Per-rig FAST precompute.

    Args:
        V: (n, 3) rest vertex positions, model units.
        F: (f, 3) int triangles (the surface; used for the energy unless ``tets`` is given).
        W: (n, m_bones) bone weights: finite, >= 0, rows summing to one (within 1e-3).
        clusters: number r of rotation clusters (k-means in weight space), or an (n,) int array
            of cluster labels (empty labels are dropped and the rest compacted).
        extra_weights: number of extra (always free) handles: B-spline bumps in weight space.
        energy: "spokes", "spokes_and_rims" (triangles only) or "elements".
        tets: optional (t, 4) int tet mesh over the same vertices; the energy then uses it.
        normalize_weights: repair W by clipping negatives and rescaling rows (else refuse).
        cache_dir: directory of the precompute cache (None: default_cache_dir(); False: off).

    Computed with one BLAS thread (``puppet.fast.blas``): the same on every machine setting.

    Attributes:
        n, m, m_bones, r: vertex, handle, bone and (actual) cluster counts.
        weights: (n, m) float32, bones then extras, rows summing to one (the renderer skins with it).
        labels: (n,) int32 cluster of each vertex.
        Q: (4m, 4m) float64 reduced Laplacian M^T L M; K: (4m, 3r) float64 M^T E; c0: float.
        dropped_elements: degenerate (zero area/volume) elements left out of the energy.
    """

    @one_blas_thread()
    def __init__(
        self,
        V,
        F,
        W,
        clusters=50,
        extra_weights: int = 0,
        energy: str = "spokes_and_rims",
        tets=None,
        *,
        normalize_weights: bool = False,
        cache_dir=None,
    ):
        if energy not in ENERGIES:
            raise FastError(f"energy: {energy!r} is not one of {ENERGIES}")
        V, F, tets = _validate_mesh(V, F, tets)
        n = V.shape[0]
        Wb = validate_weights(W, n, normalize=normalize_weights)
        extra = int(extra_weights)
        if extra < 0:
            raise FastError(f"extra_weights: {extra_weights!r} must be >= 0")
        if isinstance(clusters, (int, np.integer)):
            if clusters < 1:
                raise FastError(f"clusters: {clusters} must be >= 1")
            labels_in = None
        else:
            labels_in = np.asarray(clusters)
            if labels_in.shape != (n,) or not np.issubdtype(labels_in.dtype, np.integer) or labels_in.min() < 0:
                raise FastError(f"clusters: labels of shape {labels_in.shape}, expected ({n},) non-negative ints")
        elems = F if tets is None else tets
        if energy == "spokes_and_rims" and tets is not None:
            raise MeshError("energy: 'spokes_and_rims' needs triangles; pass energy='spokes' or 'elements' with tets")

        self.V, self.F, self.tets = V, F, tets
        self.n, self.m_bones, self.energy = n, Wb.shape[1], energy
        diag = float(np.linalg.norm(V.max(0) - V.min(0)))
        eps = 1e-12 * diag**2 if tets is None else 1e-12 * diag**3

        entry = None
        if cache_dir is not False:
            entry = Entry.keyed(Path(cache_dir) if cache_dir is not None else default_cache_dir(),
                                "fast", ".npz", code_version(), CACHE_VERSION, V, elems, Wb,
                                labels_in if labels_in is not None else int(clusters), extra, energy,
                                tets is not None)
            stored = entry.load(_read_precompute)
            if stored is not None:
                self._set(*stored)
                self.cache_hit = True
                return
        Wf = full_weights(Wb, extra) if extra else Wb
        if labels_in is None:
            labels = kmeans_weight_space(Wf, int(clusters))
        else:
            _, labels = np.unique(labels_in, return_inverse=True)
            labels = labels.astype(np.int32)
        r = int(labels.max()) + 1
        Q, K, c0, dropped = reduced_matrices(V, elems, Wf, labels, r, energy, eps)
        labels, K = _order_clusters_by_support(labels, K)
        self._set(Wf, labels, Q, K, c0, dropped)
        self.cache_hit = False
        if entry is not None:  # a read-only cache dir only costs the next run its precompute
            entry.store(lambda tmp: np.savez(tmp, weights=Wf, labels=labels, Q=Q, K=K, c0=c0, dropped=dropped))

    def _set(self, Wf, labels, Q, K, c0, dropped):
        self.weights64 = np.asarray(Wf, np.float64)
        self.weights = np.ascontiguousarray(Wf, np.float32)
        self.labels = np.asarray(labels, np.int32)
        self.m = self.weights.shape[1]
        self.r = int(self.labels.max()) + 1
        self.Q, self.K, self.c0 = np.asarray(Q), np.asarray(K), float(c0)
        self.dropped_elements = int(dropped)

    def rest_T(self) -> np.ndarray:
        """(4m, 3) float32: every handle at the identity (the rest pose)."""
        T = np.zeros((self.m, 4, 3), np.float32)
        T[:, :3, :] = np.eye(3, dtype=np.float32)
        return T.reshape(4 * self.m, 3)

    def lbs_matrix(self) -> np.ndarray:
        """(n, 4m) float64 M with V' = M @ T."""
        return lbs_matrix(self.V, self.weights64)

    def deform(self, T: np.ndarray) -> np.ndarray:
        """(n, 3) float64 deformed vertices V' = M T for T (4m, 3)."""
        Vh = np.hstack([self.V, np.ones((self.n, 1))])
        Tb = np.asarray(T, np.float64).reshape(self.m, 4, 3)
        return np.einsum("ij,ic,jcd->id", self.weights64, Vh, Tb)

    def vertex_mass(self) -> np.ndarray:
        """(n,) float64 lumped area (triangles: 1/3 per corner) or volume (tets: 1/4 per corner)."""
        if self.tets is None:
            p0, p1, p2 = (self.V[self.F[:, k]] for k in range(3))
            share = np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1) / 6.0
            elems = self.F
        else:
            a, b, c, d = (self.V[self.tets[:, k]] for k in range(4))
            share = np.abs(np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)) / 24.0
            elems = self.tets
        return np.bincount(elems.ravel(), np.repeat(share, elems.shape[1]), minlength=self.n)

    def mass_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """M^T diag(mass) M (4m, 4m) and M^T mass (4m,) for unit density (cached)."""
        if getattr(self, "_mass", None) is None:
            mass = self.vertex_mass()
            M = self.lbs_matrix()
            self._mass = (M.T @ (mass[:, None] * M), M.T @ mass)
        return self._mass

    def tolerance_probes(self) -> tuple[np.ndarray, float, float]:
        """The tolerance stop's probe rows (p, 4m) float64, bounding-box diagonal and reach (cached;
        see puppet.fast.probes)."""
        if getattr(self, "_probes", None) is None:
            self._probes = (probe_rows(self.V, self.weights64), *tolerance_scales(self.V))
        return self._probes

    def solver(self, pattern: Pattern, *, anderson_window: int = 5, dynamics: Dynamics | None = None,
               factor=None) -> Solver:
        """Factor the global step for ``pattern`` (PatternError if undetermined) and return a Solver.

        dynamics: optional :class:`Dynamics` (inertia and gravity) for secondary motion.
        factor: the pattern's Factor computed once elsewhere (shared precompute), or None."""
        return Solver(self, pattern, anderson_window=anderson_window, dynamics=dynamics,
                      factor=factor)
