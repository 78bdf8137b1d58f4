"""Bone weights: validation, extra weights (cubic B-spline bumps in weight space).

Extra weights follow the FAST app (``iso_extra.h``): seeds are farthest-point samples of the
vertices in weight space, kept away from the corners e_j; seed s has radius
rho_s = min(min_j |w_s - e_j|, push * min_{s' != s} |w_s - w_s'|) and weight
B(|W(v) - w_s| / rho_s) with the C^2 cubic B-spline bump B(x) = 1 - 6x^2 + 6x^3 (x <= 1/2),
2(1 - x)^3 (1/2 < x <= 1), 0 beyond. Bones and extras are then normalised to sum to one per
vertex so that the rest pose is every handle at the identity.
"""

from __future__ import annotations

import numpy as np

from puppet.fast.errors import WeightsError

SUM_TOLERANCE = 1e-3
"""Largest |sum_j W_ij - 1| accepted per row (rows are then renormalised exactly)."""


def validate_weights(W, n: int, *, normalize: bool = False) -> np.ndarray:
    """Checked (n, m) float64 copy of W.

    Rows must be finite, non-negative (down to -1e-6, clipped) and sum to one within
    SUM_TOLERANCE; they are then renormalised exactly. With ``normalize=True`` (a documented
    repair) negative entries are clipped to zero and every row is rescaled to sum to one;
    rows that sum to zero are still refused.
    """
    W = np.asarray(W)
    if W.ndim != 2 or W.shape[0] != n or W.shape[1] < 1:
        raise WeightsError(f"W: shape {W.shape}, expected ({n}, m_bones) for {n} vertices")
    if not np.issubdtype(W.dtype, np.floating) and not np.issubdtype(W.dtype, np.integer):
        raise WeightsError(f"W: dtype {W.dtype} is not numeric")
    W = W.astype(np.float64)
    bad = ~np.isfinite(W).all(axis=1)
    if bad.any():
        raise WeightsError(f"W: rows {np.flatnonzero(bad)[:8].tolist()} contain NaN or inf")
    if normalize:
        W = np.clip(W, 0.0, None)
    else:
        neg = (W < -1e-6).any(axis=1)
        if neg.any():
            rows = np.flatnonzero(neg)
            raise WeightsError(
                f"W: {rows.size} rows have negative weights (first rows {rows[:8].tolist()}, "
                f"min {W.min():.3g}); pass normalize_weights=True to clip and renormalise"
            )
        W = np.clip(W, 0.0, None)
    sums = W.sum(axis=1)
    zero = sums <= 1e-12
    if zero.any():
        raise WeightsError(f"W: rows {np.flatnonzero(zero)[:8].tolist()} sum to zero (vertex bound to no bone)")
    if not normalize:
        off = np.abs(sums - 1.0) > SUM_TOLERANCE
        if off.any():
            rows = np.flatnonzero(off)
            raise WeightsError(
                f"W: {rows.size} rows do not sum to one (first rows {rows[:8].tolist()}, "
                f"sums {sums[rows[:3]].round(4).tolist()}); pass normalize_weights=True to renormalise"
            )
    return W / sums[:, None]


def bspline_bump(x: np.ndarray) -> np.ndarray:
    """C^2 cubic B-spline bump of x >= 0: 1 at 0, 0 from 1 on (FAST's EASE_CUBIC_BSPLINE)."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.5, 1.0 - 6.0 * x**2 + 6.0 * x**3, 2.0 * (1.0 - x) ** 3)


def extra_weights(W: np.ndarray, count: int, *, push: float = 2.0) -> np.ndarray:
    """(n, count) float64 extra weights (before normalisation) for bone weights W (n, m_bones)."""
    if count <= 0:
        return np.zeros((W.shape[0], 0))
    n, mb = W.shape
    sq = np.einsum("ij,ij->i", W, W)
    # Squared distance to the nearest corner e_j: |W|^2 - 2 W_j + 1.
    d_corner = (sq[:, None] - 2.0 * W + 1.0).min(axis=1)
    d = d_corner.copy()
    seeds = []
    for _ in range(count):
        i = int(np.argmax(d))
        if d[i] <= 1e-12:
            raise WeightsError(
                f"W: cannot place {count} extra weights: only {len(seeds)} vertices lie away from the "
                "weight-space corners and earlier seeds (weights too close to rigid)"
            )
        seeds.append(i)
        diff = W - W[i]
        d = np.minimum(d, np.einsum("ij,ij->i", diff, diff))
    S = W[seeds]  # (count, mb)
    corner = np.sqrt(np.maximum(d_corner[seeds], 0.0))
    if count > 1:
        dss = np.sqrt(((S[:, None, :] - S[None, :, :]) ** 2).sum(-1))
        np.fill_diagonal(dss, np.inf)
        rho = np.minimum(corner, push * dss.min(axis=1))
    else:
        rho = corner
    dist = np.sqrt(np.maximum(sq[:, None] - 2.0 * W @ S.T + (S * S).sum(1)[None, :], 0.0))
    return bspline_bump(dist / rho[None, :])


def full_weights(W: np.ndarray, extra: int) -> np.ndarray:
    """(n, m_bones + extra) float64: bones then extras, rows normalised to sum to one."""
    EW = extra_weights(W, extra)
    Wf = np.hstack([W, EW])
    return Wf / Wf.sum(axis=1, keepdims=True)
