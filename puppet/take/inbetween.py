"""In-betweens of key poses in rotation space: each joint's rotation between two keys.

Per key, the frames from it to the next key are filled by its interpolation
(``puppet.take.keys.INTERPOLATIONS``): "linear" is the slerp of each joint's rotation (constant
angular speed along the shortest arc), "smooth" a C2 cubic spline in rotation space through all
the shot's keys (scipy's RotationSpline, per joint), "step" holds the key. These rotations are
the sensed joints' constraints of the in-between frames; the FAST solve fills in the free
bones from them (``Playback`` hands them on with each frame, ``Pipeline.solve`` uses them).
"""

from __future__ import annotations

import numpy as np


class Inbetweens:
    """Joint rotations of a shot at any time, from its keys'.

    key_ns: (K,) int64 key times, strictly increasing, ns. key_rot: (K, b, 3, 3) float64
    model-space joint rotations of every key. interpolation: (K,) str, one per key.
    """

    def __init__(self, key_ns, key_rot, interpolation):
        from scipy.spatial.transform import Rotation, RotationSpline

        self.key_ns = np.asarray(key_ns, np.int64)
        self.key_rot = np.asarray(key_rot, np.float64)
        self.kinds = np.asarray(interpolation)
        self._splines = None
        if len(self.key_ns) >= 2 and (self.kinds[:-1] == "smooth").any():
            seconds = self.key_ns * 1e-9
            self._splines = [RotationSpline(seconds, Rotation.from_matrix(self.key_rot[:, bone]))
                             for bone in range(self.key_rot.shape[1])]

    def at(self, play_ns) -> np.ndarray:
        """(N, b, 3, 3) float64 rotations at times play_ns (N,) ns (before the first key: the
        first key; after the last: the last; on a key: that key's, exactly)."""
        from scipy.spatial.transform import Rotation

        key_ns, key_rot = self.key_ns, self.key_rot
        t = np.asarray(play_ns, np.float64)
        K, b = key_rot.shape[:2]
        i = np.clip(np.searchsorted(key_ns, t, side="right") - 1, 0, K - 1)
        out = key_rot[i].copy()  # held: "step", on a key, outside the keys
        if K < 2:
            return out
        nxt = np.minimum(i + 1, K - 1)
        inside = (t > key_ns[i]) & (i < K - 1)
        span = np.maximum(key_ns[nxt] - key_ns[i], 1).astype(np.float64)
        a = (t - key_ns[i]) / span
        kinds = self.kinds[i]
        linear = inside & (kinds == "linear")
        if linear.any():
            r0 = Rotation.from_matrix(key_rot[i[linear]].reshape(-1, 3, 3))
            r1 = Rotation.from_matrix(key_rot[nxt[linear]].reshape(-1, 3, 3))
            turn = (r0.inv() * r1).as_rotvec() * np.repeat(a[linear], b)[:, None]
            out[linear] = (r0 * Rotation.from_rotvec(turn)).as_matrix().reshape(-1, b, 3, 3)
        smooth = inside & (kinds == "smooth")
        if smooth.any():
            for bone, spline in enumerate(self._splines):
                out[smooth, bone] = spline(t[smooth] * 1e-9).as_matrix()
        return out
