"""A pinhole camera (eye, target, up, vertical field of view) and automatic framing.

Conventions: right-handed world, OpenGL clip space; matrices are float32 (4, 4), row-major in
NumPy and applied to column vectors (clip = P @ V @ [x y z 1]).
"""

from dataclasses import dataclass, field

import numpy as np

from puppet.render.errors import RenderInputError


def _unit(v: np.ndarray, name: str) -> np.ndarray:
    norm = float(np.linalg.norm(v))
    if not np.isfinite(norm) or norm < 1e-12:
        raise RenderInputError(f"camera: {name} has zero or non-finite length: {v.tolist()}")
    return v / norm


@dataclass
class Camera:
    """Where the camera is and what it sees.

    eye, target: (3,) world positions [scene units]; up: (3,) world up direction;
    fov_deg: vertical field of view [degrees]; near, far: clip distances [scene units],
    None means chosen from the distance to the target.
    """

    eye: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 3.0]))
    target: np.ndarray = field(default_factory=lambda: np.zeros(3))
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    fov_deg: float = 35.0
    near: float | None = None
    far: float | None = None

    def __post_init__(self):
        self.eye = np.asarray(self.eye, dtype=np.float64).reshape(3)
        self.target = np.asarray(self.target, dtype=np.float64).reshape(3)
        self.up = np.asarray(self.up, dtype=np.float64).reshape(3)
        if not 1.0 <= self.fov_deg <= 170.0:
            raise RenderInputError(f"camera: fov_deg must be in [1, 170], got {self.fov_deg}")

    @classmethod
    def framing(
        cls,
        points: np.ndarray,
        *,
        aspect: float = 4 / 3,
        fov_deg: float = 35.0,
        up=(0.0, 1.0, 0.0),
        direction=(0.45, 0.3, 1.0),
        margin: float = 1.1,
        view=None,
    ) -> "Camera":
        """A camera that sees the whole bounding box of points (n, 3) from direction.

        direction: (3,) from the target toward the eye, in the frame (right, up, front) where
        front is +z turned to be perpendicular to up; view: (3,) the same in world coordinates,
        used instead of direction when given (it must not be parallel to up); aspect: width /
        height; margin: >= 1.
        """
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise RenderInputError(f"camera: points must be (n, 3) with n > 0, got {points.shape}")
        lo, hi = points.min(axis=0), points.max(axis=0)
        target = (lo + hi) / 2
        up = _unit(np.asarray(up, dtype=np.float64), "up")
        front = np.array([0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.array([0.0, -1.0, 0.0])
        front = _unit(front - up * (front @ up), "front")
        right = np.cross(up, front)
        if view is not None:
            back = _unit(np.asarray(view, dtype=np.float64), "view")
        else:
            d = np.asarray(direction, dtype=np.float64)
            back = _unit(d[0] * right + d[1] * up + d[2] * front, "direction")
        # Camera axes for the bounding-box fit.
        cam_right = _unit(np.cross(up, back), "up x direction")
        cam_up = np.cross(back, cam_right)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        rel = corners - target
        tan_y = np.tan(np.radians(fov_deg) / 2)
        tan_x = tan_y * aspect
        toward_eye = rel @ back
        need = toward_eye + np.maximum(np.abs(rel @ cam_right) / tan_x, np.abs(rel @ cam_up) / tan_y)
        distance = max(float(need.max()) * margin, 1e-3)
        return cls(eye=target + back * distance, target=target, up=up, fov_deg=fov_deg)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera axes in world space: right, up, back (back points from target to eye)."""
        back = _unit(self.eye - self.target, "eye - target")
        right = _unit(np.cross(self.up, back), "up x (eye - target)")
        return right, np.cross(back, right), back

    def view_matrix(self) -> np.ndarray:
        """World to camera (4, 4) float32."""
        right, up, back = self.basis()
        view = np.eye(4)
        view[0, :3], view[1, :3], view[2, :3] = right, up, back
        view[:3, 3] = -view[:3, :3] @ self.eye
        return view.astype(np.float32)

    def to_pixels(self, points, width: int, height: int) -> np.ndarray:
        """(n, 2) float pixel coordinates (x right, y down, from the image's top left corner)
        of world points (n, 3) in a width x height image drawn with this camera."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        clip = (self.projection_matrix(width / height).astype(np.float64)
                @ self.view_matrix().astype(np.float64)
                @ np.hstack([points, np.ones((len(points), 1))]).T)
        ndc = clip[:2] / clip[3]
        return np.stack([(ndc[0] + 1) * 0.5 * width, (1 - ndc[1]) * 0.5 * height], axis=1)

    def clip_range(self, scene_radius: float) -> tuple[float, float]:
        """(near, far) [scene units]: the set values, else from the distance and scene_radius."""
        distance = float(np.linalg.norm(self.eye - self.target))
        near = self.near if self.near is not None else max(distance - 4 * scene_radius, distance * 0.02)
        far = self.far if self.far is not None else distance + 4 * scene_radius
        return near, far

    def projection_matrix(self, aspect: float, scene_radius: float = 1.0) -> np.ndarray:
        """Camera to clip (4, 4) float32, perspective with aspect = width / height."""
        near, far = self.clip_range(scene_radius)
        f = 1.0 / np.tan(np.radians(self.fov_deg) / 2)
        proj = np.zeros((4, 4))
        proj[0, 0] = f / aspect
        proj[1, 1] = f
        proj[2, 2] = (far + near) / (near - far)
        proj[2, 3] = 2 * far * near / (near - far)
        proj[3, 2] = -1.0
        return proj.astype(np.float32)
