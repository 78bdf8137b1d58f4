"""The point handles viewers pin on the character and drag: picks (on the very frame the viewer
clicked), grabs, drags and removals, each change refactoring the solver."""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from puppet.errors import PuppetError
from puppet.view.handles import Handle, drag_target, surface_bary, surface_point
from puppet.view.protocol import MAX_HANDLES

log = logging.getLogger("puppet.view")


class HandleDesk:
    """Handles of one view: F (f, 3) int64 the rig's triangles; picker: the renderer's Picker;
    cameras: the view's Cameras; server: the ViewServer; seen: seq -> (T, camera) of a frame
    sent, or None when it left the ring; refactor_ms: list each refactor's time [ms] is added to.

    ``handles``: the current handles, replaced (never changed in place) on a pick or removal.
    A viewer's pointer keys (client, key) map to the handle it holds.
    """

    def __init__(self, F, picker, cameras, server, seen, refactor_ms: list[float]):
        self._F = np.asarray(F, np.int64)
        self._picker = picker
        self._cameras = cameras
        self._server = server
        self._seen = seen
        self.refactor_ms = refactor_ms
        self.handles: list[Handle] = []
        self._next_handle = 1
        self._keys: dict[tuple[str, int], int] = {}  # (client, key) -> handle id
        self._told_background: set = set()

    def as_dicts(self) -> list[dict]:
        return [h.as_dict() for h in self.handles]

    def _hit(self, pipeline, msg: dict):
        """(hit or None, x, y) of the viewer's click at (msg x, y) on the frame it saw (seq)."""
        frame = self._seen(msg["seq"])
        if frame is not None:
            T, camera = frame
        else:  # the frame is older than the ring: pick on the current pose
            T, camera = pipeline.T, self._cameras.get(msg["camera"]).camera()
        x, y = math.floor(msg["x"]), math.floor(msg["y"])
        return self._picker.pick(T, camera, x, y), x, y

    def bone_at(self, pipeline, msg: dict) -> int | None:
        """The bone (index into the rig's skeleton) that moves the surface most where the viewer
        clicked (its skin weights at the picked point); None: the background."""
        hit, _, _ = self._hit(pipeline, msg)
        if hit is None:
            return None
        corners = self._F[int(hit.triangle)]
        weights = np.asarray(surface_bary(hit.bary), float) @ np.asarray(pipeline.rig.W)[corners]
        return int(np.argmax(weights))

    def pick(self, pipeline, client: str, msg: dict) -> None:
        """Pin a handle where the viewer clicked (or take the one already there)."""
        start = time.perf_counter()
        hit, x, y = self._hit(pipeline, msg)
        pick_ms = (time.perf_counter() - start) * 1e3
        if hit is None:
            self._server.send_to(client, {"type": "pick_miss", "key": msg["key"]})
            if client not in self._told_background:  # once per viewer: it is also how one orbits
                self._told_background.add(client)
                self._server.warn(f"a drag that started on the background (at {x}, {y}) moves no handle; "
                                  "such drags turn the camera", client, None)
            return
        triangle = int(hit.triangle)
        bary = surface_bary(hit.bary)
        existing = next((h for h in self.handles if h.triangle == triangle and h.bary == bary), None)
        if existing is not None:
            self._keys[(client, msg["key"])] = existing.id
            self._server.send_to(client, {"type": "handle", "key": msg["key"], "handle": existing.id})
            return
        if len(self.handles) >= MAX_HANDLES:
            raise PuppetError(f"at most {MAX_HANDLES} handles: remove one (right click or double click "
                              "on it) to pin another")
        # The handle starts where its point is now (nothing jumps), then goes where it is dragged.
        point, _ = surface_point(pipeline.model, self._F, pipeline.T, triangle, bary)
        corners = tuple(int(v) for v in self._F[triangle])
        handle = Handle(self._next_handle, triangle, bary, corners, point)
        refactor_ms = self._set_handles(pipeline, self.handles + [handle])
        self._next_handle += 1
        self._keys[(client, msg["key"])] = handle.id
        self._server.send_to(client, {"type": "handle", "key": msg["key"], "handle": handle.id,
                                      "refactor_ms": round(refactor_ms, 3),
                                      "pick_ms": round(pick_ms, 2)})
        self._broadcast()
        self._cameras.touch()

    def grab(self, client: str, key: int, handle_id: int) -> None:
        """The viewer's pointer ``key`` holds handle ``handle_id`` (if it exists)."""
        if any(h.id == handle_id for h in self.handles):
            self._keys[(client, key)] = handle_id

    def held(self, client: str, key: int) -> int | None:
        """The handle the viewer's pointer holds (None: a drag that started on the background)."""
        return self._keys.get((client, key))

    def left(self, client: str) -> None:
        """The viewer left: its pointers hold nothing."""
        self._keys = {k: v for k, v in self._keys.items() if k[0] != client}

    def _set_handles(self, pipeline, handles: list[Handle]) -> float:
        """Refactor for these handles; returns ms. On a PatternError nothing changes."""
        seconds = pipeline.set_handles([h.point for h in handles])
        self.handles = handles
        for i, h in enumerate(handles):
            pipeline.handle_targets[i] = h.target
        ms = seconds * 1e3
        self.refactor_ms.append(ms)
        log.info("view: %d handles, refactor %.2f ms", len(handles), ms)
        return ms

    def remove(self, pipeline, handle_id: int) -> None:
        kept = [h for h in self.handles if h.id != handle_id]
        if len(kept) == len(self.handles):
            return
        self._set_handles(pipeline, kept)
        self._keys = {k: v for k, v in self._keys.items() if v != handle_id}
        self._broadcast()
        self._cameras.touch()

    def drag(self, pipeline, handle_id: int, camera_id: int, x: float, y: float) -> None:
        """Move the handle's target under image point (x, y) [px] of camera ``camera_id``, at
        the depth it had."""
        index = next((i for i, h in enumerate(self.handles) if h.id == handle_id), None)
        if index is None:
            return
        handle = self.handles[index]
        width, height = self._cameras.width, self._cameras.height
        x = min(max(x, -width), 2 * width)  # a cursor far off the image moves no further
        y = min(max(y, -height), 2 * height)
        camera = self._cameras.get(camera_id).camera()
        view_proj = self._picker.view_proj(camera)
        back = camera.basis()[2]
        target = drag_target(view_proj, width, height, x, y, handle.target, back)
        if target is None or not np.isfinite(target).all():
            return
        handle.target = target
        pipeline.handle_targets[index] = target
        self._cameras.touch()

    def _broadcast(self) -> None:
        self._server.send_to(None, {"type": "handles", "handles": self.as_dicts()})
