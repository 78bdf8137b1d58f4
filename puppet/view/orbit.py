"""An orbit camera for the view: yaw and pitch about a target, distance, pan; presets.

Angles in radians; yaw turns about the world up, pitch lifts toward it. The frame (right, up,
front) is the one ``Camera.framing`` uses: front is +z made perpendicular to up.
"""

from __future__ import annotations

import math

import numpy as np

from puppet.render import Camera

PITCH_LIMIT = math.radians(85.0)
PRESETS = {"front": (0.0, 0.15), "side": (math.pi / 2, 0.15), "back": (math.pi, 0.25),
           "top": (0.0, PITCH_LIMIT)}


class OrbitCamera:
    """A camera orbiting a target. ``camera()`` gives the renderer's Camera (cached until the next
    change); ``version`` counts changes."""

    def __init__(self, start: Camera):
        up = np.asarray(start.up, np.float64)
        self.up = up / np.linalg.norm(up)
        front = np.array([0.0, 0.0, 1.0]) if abs(self.up[2]) < 0.9 else np.array([0.0, -1.0, 0.0])
        front = front - self.up * (front @ self.up)
        self.front = front / np.linalg.norm(front)
        self.right = np.cross(self.up, self.front)
        self.fov_deg = start.fov_deg
        self._start = start
        self.version = 0
        self.reset()

    def reset(self) -> None:
        """Back to the starting camera."""
        start = self._start
        back = start.eye - start.target
        self.distance = float(np.linalg.norm(back))
        back = back / self.distance
        self.yaw = math.atan2(float(back @ self.right), float(back @ self.front))
        self.pitch = math.asin(float(np.clip(back @ self.up, -1.0, 1.0)))
        self.target = np.array(start.target, np.float64)
        self._changed()
        self._camera = start

    @property
    def pristine(self) -> bool:
        """True while the camera is the starting one (never moved, or reset)."""
        return self._camera is self._start

    def _changed(self) -> None:
        self.version += 1
        self._camera = None

    def back(self) -> np.ndarray:
        """(3,) unit vector from the target toward the eye."""
        c = math.cos(self.pitch)
        return (c * math.sin(self.yaw)) * self.right + math.sin(self.pitch) * self.up + \
            (c * math.cos(self.yaw)) * self.front

    def orbit(self, dyaw: float, dpitch: float) -> None:
        self.yaw = (self.yaw + dyaw) % (2 * math.pi)
        self.pitch = float(np.clip(self.pitch + dpitch, -PITCH_LIMIT, PITCH_LIMIT))
        self._changed()

    def pan(self, dx: float, dy: float) -> None:
        """Move the target across the view by (dx, dy) fractions of the view height."""
        back = self.back()
        right = np.cross(self.up, back)
        right /= np.linalg.norm(right)
        up = np.cross(back, right)
        height = 2 * self.distance * math.tan(math.radians(self.fov_deg) / 2)
        self.target = self.target + height * (-dx * right + dy * up)
        self._changed()

    def zoom(self, factor: float) -> None:
        """Multiply the distance by factor (< 1 comes closer)."""
        self.distance = float(np.clip(self.distance * factor, 1e-3, 1e3))
        self._changed()

    def preset(self, name: str) -> None:
        yaw, pitch = PRESETS[name]
        self.yaw, self.pitch = yaw, pitch
        self._changed()

    def camera(self) -> Camera:
        if self._camera is None:
            self._camera = Camera(eye=self.target + self.distance * self.back(), target=self.target,
                                  up=self.up, fov_deg=self.fov_deg)
        return self._camera

    def copy(self) -> "OrbitCamera":
        other = OrbitCamera(self._start)
        other.yaw, other.pitch, other.distance = self.yaw, self.pitch, self.distance
        other.target = self.target.copy()
        other._changed()
        return other
