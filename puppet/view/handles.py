"""Point handles: surface points picked on a frame and dragged; the geometry of a drag.

A handle is stored as (triangle, barycentric) so it follows the deformation, and the solver holds
exactly that surface point (a ``Pattern.positional`` point: sum_k b_k V'[v_k] over the
triangle's corners) where the cursor puts it. Positions are model units; image positions are
continuous coordinates of the view's frames: x right, y down, pixel (i, j) covers
[i, i+1) x [j, j+1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from puppet.view.errors import ViewError


def surface_bary(bary) -> tuple[float, float, float]:
    """Barycentric weights (3,) as read from a pick (float32, may stray a rounding outside the
    triangle) made exact: clipped to >= 0 and divided by their sum (float64)."""
    b = np.clip(np.asarray(bary, np.float64).reshape(3), 0.0, None)
    total = b.sum()
    if not np.isfinite(total) or total <= 0.0:
        raise ViewError(f"pick: barycentric weights {bary!r} have no positive part")
    b = b / total
    return float(b[0]), float(b[1]), float(b[2])


@dataclass
class Handle:
    """id: the view's handle number. triangle, bary: the picked surface point (bary (3,) float64,
    summing to 1); corners: the triangle's vertex indices. target: (3,) where that point is held
    (model units)."""

    id: int
    triangle: int
    bary: tuple[float, float, float]
    corners: tuple[int, int, int]
    target: np.ndarray

    @property
    def point(self) -> tuple[tuple[int, int, int], tuple[float, float, float]]:
        """The solver's positional point ((v0, v1, v2), (b0, b1, b2)) this handle holds."""
        return self.corners, self.bary

    def as_dict(self) -> dict:
        return {"id": self.id, "triangle": self.triangle,
                "bary": [round(float(b), 4) for b in self.bary]}


def deformed_points(model, T: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """(k, 3) float64 deformed positions V' = M T of the given vertices (k,)."""
    Vh = np.hstack([model.V[vertices], np.ones((len(vertices), 1))])
    blocks = np.asarray(T, np.float64).reshape(model.m, 4, 3)
    return np.einsum("ij,ic,jcd->id", model.weights64[vertices], Vh, blocks)


def surface_point(model, F: np.ndarray, T: np.ndarray, triangle: int, bary) -> tuple[np.ndarray, np.ndarray]:
    """(point (3,), corners (3, 3)) of the barycentric point on the deformed triangle."""
    corners = deformed_points(model, T, np.asarray(F[triangle], np.int64))
    return np.asarray(bary, np.float64) @ corners, corners


def pixel_ray(view_proj: np.ndarray, width: int, height: int, x: float, y: float):
    """(origin (3,), direction (3,) unit) of the ray through image position (x, y) of a frame drawn with
    view_proj ((4, 4) world to clip, rows flipped as the renderer draws)."""
    ndc_x = 2.0 * float(x) / width - 1.0
    ndc_y = 2.0 * float(y) / height - 1.0
    inverse = np.linalg.inv(np.asarray(view_proj, np.float64))
    near = inverse @ np.array([ndc_x, ndc_y, -1.0, 1.0])
    far = inverse @ np.array([ndc_x, ndc_y, 1.0, 1.0])
    near, far = near[:3] / near[3], far[:3] / far[3]
    direction = far - near
    return near, direction / np.linalg.norm(direction)


def drag_target(view_proj, width, height, x, y, anchor: np.ndarray, view_back: np.ndarray):
    """Where the cursor at pixel (x, y) puts a point dragged in the plane through ``anchor`` (3,)
    facing the camera (normal ``view_back``); None when the ray runs parallel to it."""
    origin, direction = pixel_ray(view_proj, width, height, x, y)
    denom = float(direction @ view_back)
    if abs(denom) < 1e-9:
        return None
    s = float((anchor - origin) @ view_back) / denom
    return origin + s * direction


def project(view_proj: np.ndarray, width: int, height: int, points: np.ndarray) -> np.ndarray:
    """(k, 2) image positions (x, y) of world points (k, 3)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    clip = np.hstack([points, np.ones((len(points), 1))]) @ np.asarray(view_proj, np.float64).T
    w = np.where(np.abs(clip[:, 3:4]) < 1e-12, 1e-12, clip[:, 3:4])
    ndc = clip[:, :2] / w
    return np.stack([(ndc[:, 0] + 1) * width / 2, (ndc[:, 1] + 1) * height / 2], axis=1)
