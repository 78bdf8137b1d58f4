"""Frames for viewers: which camera gets the next one, whether its picture changed, the render
(or the loop's own frame reused), and the ring of frames sent that picks refer to."""

from __future__ import annotations

import math
import time

import numpy as np

from puppet.view.encoder import FrameEncoder

RING = 64                 # frames remembered for picking (about 1 s at 60 fps)
VIEW_SHARE = 0.6          # the most of the loop's wall time spent rendering for viewers
KEEPALIVE_S = 2.0         # an idle view (nothing moved, camera still) sends one frame this often
STILL = 1 / 2000          # a pose whose T entries all moved less than this times the model's size
                          # is the same picture (the solver still settling; ~0.2 px at 480 px)


class ViewFrames:
    """Frames of width x height [px] of a pipeline's renderer for the view's cameras (Cameras),
    with onion skins from key_poses (KeyPoses), encoded and handed to ``publish``; overlay:
    bones drawn; max_fps: most frames per second per camera.

    ``seq``: frames sent; ``rendered``, ``reused``: frames drawn for viewers, and frames that
    were the loop's own.
    """

    def __init__(self, pipeline, cameras, key_poses, server, *, width: int, height: int, overlay: bool,
                 max_fps: float, publish):
        self._cameras = cameras
        self._key_poses = key_poses
        self._server = server
        self.overlay = overlay
        self.max_fps = max_fps
        m = pipeline.model.m
        self._ring_T = np.zeros((RING, 4 * m, 3), np.float32)
        self._ring_seq = np.full(RING, -1, np.int64)
        self._ring_camera: list = [None] * RING
        self._T_scratch = np.zeros((4 * m, 3), np.float32)
        V = np.asarray(pipeline.model.V)
        self._still_T = STILL * max(float(np.ptp(V, axis=0).max()), 1e-6)
        self._last: dict[int, tuple] = {}          # camera -> (T copy, version, overlay, states, draft, onion)
        self._last_render_s: dict[int, float] = {}
        self._next_render_s = 0.0
        self.seq = 0
        self.rendered = 0
        self.reused = 0
        self.encoder = FrameEncoder(width, height, publish)

    def seen(self, seq: int):
        """(T (4m, 3), Camera) of frame ``seq`` as sent, or None when it left the ring."""
        slot = seq % RING
        if self._ring_seq[slot] == seq:
            return self._ring_T[slot], self._ring_camera[slot]
        return None

    def offer(self, pipeline, image, reading, now: float) -> None:
        """Render one frame for viewers when one has credit, the encoder is free, the loop's
        share allows it and a camera's picture changed (or its keep-alive is due)."""
        demand = self._server.demand
        if not demand or self.encoder.busy or now < self._next_render_s:
            return
        camera_id = self._choose_camera(pipeline, demand, now)
        if camera_id is None:
            return
        self._render(pipeline, camera_id, image, reading, now)

    def _choose_camera(self, pipeline, demand, now: float) -> int | None:
        force = self._server.force
        best, best_t = None, math.inf
        period = 1.0 / self.max_fps
        for camera_id in demand:
            last_t = self._last_render_s.get(camera_id, -math.inf)
            if now - last_t < period:
                continue
            if camera_id not in force and now - last_t < KEEPALIVE_S \
                    and not self._dirty(pipeline, camera_id, now):
                continue
            if last_t < best_t:
                best, best_t = camera_id, last_t
        return best

    def _dirty(self, pipeline, camera_id: int, now: float) -> bool:
        last = self._last.get(camera_id)
        if last is None:
            return True
        T, version, overlay, states, draft, onion = last
        camera = self._cameras.orbits.get(camera_id)
        if (draft and not self._cameras.draft(now)) or overlay != self.overlay \
                or onion != self._key_poses.version \
                or camera is None or version != camera.version or states != pipeline.bone_states:
            return True
        # A still pose: the solver's answer still settles by far less than a pixel per solve.
        scratch = self._T_scratch
        np.subtract(T, pipeline.T, out=scratch)
        np.abs(scratch, out=scratch)
        return bool(scratch.max() > self._still_T)

    def _render(self, pipeline, camera_id: int, image, reading, now: float) -> None:
        orbit = self._cameras.get(camera_id)
        renderer = pipeline.renderer
        buffer = self.encoder.buffer()
        camera = orbit.camera()
        if camera_id == 0 and orbit.pristine and image is not None and self.overlay == pipeline.overlay:
            np.copyto(buffer, image)
            self.reused += 1
        else:
            start = time.monotonic()
            own = renderer.camera
            if camera is not own:
                renderer.camera = camera
            try:
                if self.overlay:
                    renderer.draw(pipeline.T, bones=pipeline.bone_segments,
                                  bone_states=pipeline.bone_states, out=buffer)
                else:
                    renderer.draw(pipeline.T, out=buffer)
            finally:
                if camera is not own:
                    renderer.camera = own
            # The loop's rate comes first: after a render of d seconds for viewers, the next one
            # waits d (1 / VIEW_SHARE - 1) seconds, so viewers get at most that share of its time.
            end = time.monotonic()
            self._next_render_s = end + (end - start) * (1.0 / VIEW_SHARE - 1.0)
            self.rendered += 1
        if self._key_poses.shown:
            self._key_poses.draw_over(buffer, camera_id, orbit, camera)
        self.seq += 1
        seq = self.seq
        slot = seq % RING
        np.copyto(self._ring_T[slot], pipeline.T)
        self._ring_seq[slot] = seq
        self._ring_camera[slot] = camera
        draft = self._cameras.draft(now)
        previous = self._last.get(camera_id)
        T_copy = previous[0] if previous is not None else np.empty_like(pipeline.T)
        np.copyto(T_copy, pipeline.T)
        self._last[camera_id] = (T_copy, orbit.version, self.overlay, list(pipeline.bone_states), draft,
                                 self._key_poses.version)
        self._last_render_s[camera_id] = now
        self._server.force.discard(camera_id)
        self.encoder.submit(buffer, seq, camera_id, int(reading.t_ns), draft)

    def close(self) -> None:
        self.encoder.close()
