"""The viewers' cameras: the shared one (id 0) and a viewer's own (a copy of it), moved by
the page's orbit, pan and zoom (merged into one change per camera and loop frame)."""

from __future__ import annotations

import time

from puppet.view.orbit import OrbitCamera

ORBIT_RAD_PER_PX = 0.01
INTERACTION_S = 0.3       # frames are drafts until this long after the last camera/handle move


class Cameras:
    """Orbit cameras by id, starting from ``start`` (a Camera), for width x height [px] frames;
    ``last_interaction``: monotonic time [s] of the last camera or handle move."""

    def __init__(self, start, width: int, height: int):
        self.orbits: dict[int, OrbitCamera] = {0: OrbitCamera(start)}
        self.width, self.height = width, height
        self.last_interaction = -1e9

    def get(self, camera_id: int) -> OrbitCamera:
        """Camera ``camera_id``, made as a copy of the shared one on first use."""
        camera = self.orbits.get(camera_id)
        if camera is None:
            camera = self.orbits[camera_id] = self.orbits[0].copy()
        return camera

    def touch(self) -> None:
        """Something moved: frames are drafts for INTERACTION_S."""
        self.last_interaction = time.monotonic()

    def draft(self, now: float) -> bool:
        """True while a move is recent (a frame rendered now is a draft)."""
        return now - self.last_interaction < INTERACTION_S

    def move(self, camera_id: int, dx: float, dy: float, px: float, py: float, zoom: float) -> None:
        """One merged change: orbit by (dx, dy) [px], pan by (px, py) [px], zoom by a factor."""
        camera = self.get(camera_id)
        limit = 2.0 * self.width  # pixels per frame: a bogus message cannot throw the camera away
        dx, dy, px, py = (min(max(v, -limit), limit) for v in (dx, dy, px, py))
        zoom = min(max(zoom, 0.05), 20.0)
        if dx or dy:
            camera.orbit(-dx * ORBIT_RAD_PER_PX, dy * ORBIT_RAD_PER_PX)
        if px or py:
            camera.pan(px / self.height, py / self.height)
        if zoom != 1.0:
            camera.zoom(zoom)
        self.touch()

    def preset(self, camera_id: int, name: str) -> None:
        self.get(camera_id).preset(name)
        self.touch()

    def reset(self, camera_id: int) -> None:
        self.get(camera_id).reset()
        self.touch()

    def own(self, camera_id: int) -> None:
        """The viewer takes its own camera, starting where the shared one is."""
        self.orbits[camera_id] = self.orbits[0].copy()

    def drop(self, camera_id: int) -> None:
        """A viewer with its own camera left (the shared one stays)."""
        if camera_id != 0:
            self.orbits.pop(camera_id, None)
