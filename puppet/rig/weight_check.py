"""Validation of skinning weights: shape, finiteness, non-negativity, partition of unity."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from puppet.rig.errors import RigError

TOLERANCE = 1e-6


@dataclass(frozen=True)
class WeightReport:
    """What a user needs to trust a weight matrix.

    ok:            every check passed.
    min_weight:    smallest entry (>= -TOLERANCE when ok).
    max_sum_error: max over vertices of |Σ_j w_ij − 1|.
    unused_bones:  names of bones whose weight never exceeds 0.01 (a warning, not a failure).
    problems:      one line per failed check.
    """

    ok: bool
    min_weight: float
    max_sum_error: float
    unused_bones: tuple[str, ...] = ()
    problems: tuple[str, ...] = field(default=())

    def summary(self) -> str:
        state = "ok" if self.ok else "FAILED: " + "; ".join(self.problems)
        text = f"{state} (min {self.min_weight:.2e}, max |row sum - 1| {self.max_sum_error:.2e})"
        if self.unused_bones:
            text += f"; bones with no influence: {', '.join(self.unused_bones)}"
        return text


def check_weights(W: np.ndarray, vertex_count: int, bone_names) -> WeightReport:
    """Validate W: (n, bones) float against a mesh of ``vertex_count`` vertices."""
    bone_names = tuple(bone_names)
    problems = []
    W = np.asarray(W)
    if W.ndim != 2 or W.shape != (vertex_count, len(bone_names)):
        return WeightReport(False, float("nan"), float("nan"), (),
                            (f"shape {W.shape}, expected ({vertex_count}, {len(bone_names)})",))
    if not np.isfinite(W).all():
        rows = np.flatnonzero(~np.isfinite(W).all(axis=1))
        problems.append(f"{len(rows)} vertices have non-finite weights (first: vertex {rows[0]})")
        return WeightReport(False, float("nan"), float("nan"), (), tuple(problems))
    min_weight = float(W.min()) if W.size else 0.0
    sums = W.sum(axis=1)
    max_sum_error = float(np.abs(sums - 1.0).max()) if len(sums) else 0.0
    if min_weight < -TOLERANCE:
        v, j = np.unravel_index(int(W.argmin()), W.shape)
        problems.append(f"negative weight {min_weight:.3g} at vertex {v}, bone {bone_names[j]!r}")
    if max_sum_error > TOLERANCE:
        v = int(np.abs(sums - 1.0).argmax())
        problems.append(f"weights of vertex {v} sum to {sums[v]:.6g}, not 1")
    unused = tuple(n for n, w in zip(bone_names, W.max(axis=0) if len(W) else []) if w < 0.01)
    return WeightReport(not problems, min_weight, max_sum_error, unused, tuple(problems))


def normalize_weights(W: np.ndarray, *, path=None, field_name: str = "weights") -> np.ndarray:
    """Clip tiny negatives to 0 and rescale rows to sum to 1; (n, m) float64 out.

    Raises RigError naming the first vertex whose weights are all zero.
    """
    W = np.clip(np.asarray(W, np.float64), 0.0, None)
    sums = W.sum(axis=1)
    bad = np.flatnonzero(sums <= 1e-12)
    if len(bad):
        raise RigError(f"{len(bad)} vertices have no weight at all (first: vertex {bad[0]})",
                       path=path, field=field_name)
    W /= sums[:, None]
    return W
