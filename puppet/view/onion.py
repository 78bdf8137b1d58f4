"""Onion skins: the previous and the next key of a shot drawn as tinted, translucent ghosts
(with an outline) over the live character in the view's frames.

Each key's ghost is solved once by FAST (its own cold ``Pipeline`` solve of the key's ticks,
cached by the key's pose); the ghosts' layer is drawn once per camera and pose pair (two
renders and two coverage passes) into a per-pixel weight W and premultiplied colour A, and each
frame then takes ``frame = (frame W + A) / 256`` in preallocated uint16 buffers (no allocation).
"""

from __future__ import annotations

import time

import numpy as np

from puppet.reading import Reading

# Ghost tints, none of the bone legend's colours (puppet.render.BONE_STATE_COLORS: green, blue,
# grey, red, yellow), each named in the page's ghost legend (GHOST_LEGEND).
PREVIOUS_RGB = (150.0, 80.0, 255.0)   # the previous key's tint (violet)
NEXT_RGB = (255.0, 140.0, 0.0)        # the next key's tint (orange)
COMPARE_RGB = (255.0, 60.0, 220.0)    # another take compared with the one reviewed (magenta)
GHOST_LEGEND = [{"what": "previous key", "color": "#9650ff"},
                {"what": "next key", "color": "#ff8c00"},
                {"what": "compared take", "color": "#ff3cdc"}]
GHOST_ALPHA = 0.45                    # a ghost's body over the frame
EDGE_ALPHA = 0.9                      # its outline
TINT = 0.6                            # tint's share of a ghost's colour (the rest: its shading)


def neighbours(keys, playhead: int):
    """(previous, next) keys around frame ``playhead``: the last key before it and the first
    after it (None where there is none); ``keys`` in frame order."""
    before = [k for k in keys if k.frame < playhead]
    after = [k for k in keys if k.frame > playhead]
    return (before[-1] if before else None), (after[0] if after else None)


def pose_id(key) -> tuple:
    """What a key's ghost depends on: its ticks and ok flags."""
    return (np.asarray(key.ticks).tobytes(), np.asarray(key.ok).tobytes())


class OnionSkins:
    """Ghosts of keys for one view: rig (the view's), width and height (its frames, pixels).

    ghost_T(key) -> (4m, 3) float32 handle transforms of the key's pose (solved once, cached).
    layer(camera_id, key, draw) -> the (W, A) of that camera and ghost pair, drawn by
    ``draw`` when ``key`` changed. apply(image, layer): the layer over ``image``.
    """

    def __init__(self, rig, width: int, height: int):
        self.rig = rig
        self.width, self.height = int(width), int(height)
        self.solves = 0
        self._solver = None
        self._T: dict[tuple, np.ndarray] = {}
        self._layers: dict[int, tuple] = {}  # camera -> (key, W (h, w, 1) uint16, A (h, w, 3) uint16)
        self._scratch = np.zeros((height, width, 3), np.uint16)
        self.shade = np.zeros((height, width, 3), np.uint8)
        self.cover = np.zeros((height, width), np.float32)

    def ghost_T(self, key) -> np.ndarray:
        """The key's pose solved by FAST from its ticks (cold, to convergence), cached."""
        ident = pose_id(key)
        T = self._T.get(ident)
        if T is None:
            from puppet.loop import Pipeline

            if self._solver is None:
                self._solver = Pipeline(self.rig, render=False)
            ids = np.asarray(self.rig.servo_map.ids)
            self._solver.restart()
            self._solver.solve(Reading(time.monotonic_ns(), ids, np.asarray(key.ticks, np.int32),
                                       np.asarray(key.ok, bool)))
            T = self._T[ident] = self._solver.T.copy()
            self.solves += 1
        return T

    def forget(self, keys) -> None:
        """Drop cached ghosts of poses no longer among ``keys``."""
        kept = {pose_id(k) for k in keys}
        for ident in [i for i in self._T if i not in kept]:
            del self._T[ident]

    def drop_camera(self, camera_id: int) -> None:
        self._layers.pop(camera_id, None)

    def layer(self, camera_id: int, key, ghosts, draw) -> tuple:
        """The camera's layer (key, W, A, box) for ``key`` (naming camera pose and ghosts); when
        it changed, made from ghosts [(T, rgb)] with draw(T) -> (the shaded frame (h, w, 3)
        uint8, its cover (h, w) float32: > 0 where the character is)."""
        cached = self._layers.get(camera_id)
        if cached is not None and cached[0] == key:
            return cached
        h, w = self.height, self.width
        W = np.ones((h, w, 1), np.float32)
        A = np.zeros((h, w, 3), np.float32)
        top, bottom, left, right = h, 0, w, 0
        for T, rgb in ghosts:
            shaded, cover = draw(T)
            rows, cols = np.nonzero(cover > 0)
            if not len(rows):
                continue
            # the ghost's box with a pixel of margin: the outline test looks one pixel around
            y0, y1 = max(rows.min() - 1, 0), min(rows.max() + 2, h)
            x0, x1 = max(cols.min() - 1, 0), min(cols.max() + 2, w)
            top, bottom, left, right = min(top, y0), max(bottom, y1), min(left, x0), max(right, x1)
            inside = cover[y0:y1, x0:x1] > 0
            inner = inside.copy()  # eroded by one pixel: what is left of inside is the outline
            inner[1:, :] &= inside[:-1, :]
            inner[:-1, :] &= inside[1:, :]
            inner[:, 1:] &= inside[:, :-1]
            inner[:, :-1] &= inside[:, 1:]
            alpha = np.where(inside & ~inner, EDGE_ALPHA, np.where(inside, GHOST_ALPHA, 0.0))
            alpha = alpha.astype(np.float32)[..., None]
            colour = ((1.0 - TINT) * shaded[y0:y1, x0:x1].astype(np.float32)
                      + TINT * np.asarray(rgb, np.float32))
            A[y0:y1, x0:x1] = A[y0:y1, x0:x1] * (1.0 - alpha) + alpha * colour
            W[y0:y1, x0:x1] *= 1.0 - alpha
        box = (slice(top, max(bottom, top)), slice(left, max(right, left)))
        cached = (key, np.rint(W[box] * 256).astype(np.uint16),
                  np.rint(A[box] * 256).astype(np.uint16), box)
        self._layers[camera_id] = cached
        return cached

    def apply(self, image: np.ndarray, layer: tuple) -> None:
        """image (h, w, 3) uint8, in place: (image W + A) / 256 within the layer's box
        (preallocated buffers)."""
        _, W, A, box = layer
        image = image[box]
        scratch = self._scratch[:W.shape[0], :W.shape[1]]
        np.multiply(image, W, out=scratch)
        np.add(scratch, A, out=scratch)
        np.right_shift(scratch, 8, out=scratch)
        np.copyto(image, scratch, casting="unsafe")

    def close(self) -> None:
        if self._solver is not None:
            self._solver.close()
            self._solver = None
