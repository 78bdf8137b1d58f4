"""Key reduction: few keys that reproduce a sampled animation curve within a tolerance.

A curve is one channel of one joint sampled on every frame: rotations as unit quaternions
(x, y, z, w), kept on one hemisphere from frame to frame, or translations (x, y, z). The reduced
curve keeps a subset of the frames as keys with their sampled values, interpolated LINEARly as
the reader does it:

- glTF 2.0 (the spec's LINEAR sampler): translations lerp; rotations slerp, the short way.
- Blender 5.0's glTF importer: every component is an F-curve with LINEAR keys, so rotations are
  lerped per component and then normalized (nlerp) when the pose is evaluated; the key values
  reach the F-curves unchanged up to one fixed rotation per bone (the rest pose), which leaves
  both errors the same.

``reduce_curve`` keeps the first and the last frame, and any forced frames (a shot's key poses),
and from each key reaches as far as it can, never past the next forced frame (a doubling search,
then bisection) while every frame in between stays within the tolerance under
*both* evaluations: rotations within ``tol`` degrees (the angle of the rotation between the
evaluated and the sampled one), translations within ``tol`` model units (Euclidean). The result
is greedy, not proven minimal; every kept segment is checked frame by frame.

Why LINEAR, not CUBICSPLINE: Blender 5.0's importer drops a CUBICSPLINE sampler's tangents and
puts AUTO Bezier handles on the keys instead, so a cubic curve fitted here would not be the curve
Blender plays. A LINEAR key is played as written by every reader.

Pure numpy, run once per channel when a file is closed (not on the per-frame path). Shapes:
times (N,) seconds, increasing; values (N, 4) or (N, 3) float.
"""

from __future__ import annotations

import numpy as np

KINDS = ("rotation", "translation")
READERS = ("gltf", "blender")


def rotation_angle_deg(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(...,) degrees of the rotation between unit quaternions p and q (..., 4) (either sign)."""
    d = np.minimum(np.linalg.norm(p - q, axis=-1), np.linalg.norm(p + q, axis=-1))
    return np.degrees(4.0 * np.arcsin(np.clip(d / 2.0, 0.0, 1.0)))


def _interpolate(a: np.ndarray, b: np.ndarray, t: np.ndarray, kind: str, reader: str) -> np.ndarray:
    """(k, c) values between key values a, b (c,) at fractions t (k,) in [0, 1]."""
    t = t[:, None]
    if kind == "translation":
        return (1.0 - t) * a + t * b
    if np.dot(a, b) < 0.0:  # both readers take the short way
        b = -b
    if reader == "blender":
        q = (1.0 - t) * a + t * b
        return q / np.linalg.norm(q, axis=1, keepdims=True)
    omega = float(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0)))
    if omega < 1e-9:
        return np.broadcast_to(a, (len(t), len(a))).copy()
    s = np.sin(omega)
    return (np.sin((1.0 - t) * omega) * a + np.sin(t * omega) * b) / s


def _error(evaluated: np.ndarray, values: np.ndarray, kind: str) -> np.ndarray:
    if kind == "rotation":
        return rotation_angle_deg(evaluated, values)
    return np.linalg.norm(evaluated - values, axis=-1)


def _check(kind: str, tol: float) -> None:
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"tolerance must be a finite number > 0, got {tol!r}")


def evaluate(times: np.ndarray, values: np.ndarray, keys: np.ndarray, kind: str,
             reader: str = "gltf") -> np.ndarray:
    """(N, c) the reduced curve read back at every time: keys (K,) int frame indices (ascending,
    the first 0 and the last N - 1) with their values, interpolated as ``reader`` does."""
    if reader not in READERS:
        raise ValueError(f"reader must be one of {READERS}, got {reader!r}")
    times = np.asarray(times, np.float64)
    values = np.asarray(values, np.float64)
    keys = np.asarray(keys, np.int64)
    out = np.empty_like(values)
    for i, j in zip(keys[:-1], keys[1:]):
        t = (times[i:j + 1] - times[i]) / (times[j] - times[i])
        out[i:j + 1] = _interpolate(values[i], values[j], t, kind, reader)
    if len(keys) == 1:
        out[:] = values[keys[0]]
    return out


def curve_error(times: np.ndarray, values: np.ndarray, keys: np.ndarray, kind: str) -> np.ndarray:
    """(N,) the error at every frame of the reduced curve, the larger of the two readers'
    (degrees for rotations, model units for translations)."""
    values = np.asarray(values, np.float64)
    return np.max([_error(evaluate(times, values, keys, kind, r), values, kind) for r in READERS],
                  axis=0)


def _fits(times: np.ndarray, values: np.ndarray, i: int, j: int, kind: str, tol: float) -> bool:
    """Whether one segment from key i to key j reproduces frames i..j within tol for both readers."""
    if j - i < 2:
        return True
    t = (times[i + 1:j] - times[i]) / (times[j] - times[i])
    inside = values[i + 1:j]
    return all(float(_error(_interpolate(values[i], values[j], t, kind, r), inside, kind).max()) <= tol
               for r in READERS)


def reduce_curve(times: np.ndarray, values: np.ndarray, kind: str, tol: float,
                 forced=()) -> np.ndarray:
    """(K,) int64 ascending frame indices of the kept keys (first and last frame, and every frame
    in ``forced``, included) so that ``curve_error(times, values, keys, kind) <= tol`` at every
    frame.

    times: (N,) increasing seconds; values: (N, 4) unit quaternions on one hemisphere from frame
    to frame (kind "rotation", tol in degrees) or (N, 3) translations (kind "translation", tol in
    model units); forced: frame indices in 0..N-1 that must be keys (any order)."""
    _check(kind, tol)
    times = np.asarray(times, np.float64)
    values = np.asarray(values, np.float64)
    n = len(values)
    if n <= 2:
        return np.arange(n, dtype=np.int64)
    forced = np.asarray(forced, np.int64).reshape(-1)
    if forced.size and (forced.min() < 0 or forced.max() > n - 1):
        raise ValueError(f"forced frames must be within 0..{n - 1}, got {forced.min()}..{forced.max()}")
    anchors = np.unique(np.concatenate([[0, n - 1], forced]))
    keys = [0]
    for start, end in zip(anchors[:-1], anchors[1:]):
        keys += _reduce_span(times, values, int(start), int(end), kind, tol)
    return np.asarray(keys, np.int64)


def _reduce_span(times, values, start: int, end: int, kind: str, tol: float) -> list[int]:
    """Kept keys after ``start`` up to and including ``end`` (greedy: from each key as far as the
    segment fits)."""
    keys, i = [], start
    while i < end:
        good, step = i + 1, 1  # a segment with no frame inside always fits
        while good + step <= end and _fits(times, values, i, good + step, kind, tol):
            good, step = good + step, 2 * step
        bad = min(good + step, end + 1)  # bisect between the last fit and the first miss
        while bad - good > 1:
            mid = (good + bad) // 2
            if _fits(times, values, i, mid, kind, tol):
                good = mid
            else:
                bad = mid
        keys.append(good)
        i = good
    return keys
