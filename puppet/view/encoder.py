"""JPEG encoding on its own thread, fed through one latest-wins slot (never a queue).

The loop renders into one of two preallocated images and submits it; the encoder thread takes
the newest (an older frame still waiting is dropped and counted), encodes it with simplejpeg
(libjpeg-turbo; the GIL is released while it encodes) and hands the bytes to ``publish``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import simplejpeg

QUALITY_SHARP = 82
QUALITY_DRAFT = 50


@dataclass(frozen=True)
class EncodedFrame:
    """seq: frame number; camera: camera id; reading_t_ns: the reading it shows (monotonic ns);
    draft: a cheaper frame (moving camera or handle); jpeg: the image."""

    seq: int
    camera: int
    reading_t_ns: int
    draft: bool
    jpeg: bytes


class FrameEncoder:
    """Encodes submitted frames on a daemon thread.

    width, height: image size (pixels). publish: called on the encoder thread with each
    EncodedFrame. Fields: encoded, dropped (frames replaced before they were encoded),
    encode_ns (total time encoding).
    """

    def __init__(self, width: int, height: int, publish):
        self._images = [np.zeros((height, width, 3), np.uint8) for _ in range(2)]
        self._publish = publish
        self._cond = threading.Condition()
        self._pending: tuple | None = None  # (buffer index, seq, camera, reading_t_ns, draft)
        self._encoding = -1                 # buffer index being encoded, -1: none
        self._stop = False
        self.encoded = 0
        self.dropped = 0
        self.encode_ns = 0
        self._thread = threading.Thread(target=self._run, name="view-encoder", daemon=True)
        self._thread.start()

    @property
    def busy(self) -> bool:
        """A frame waits or is being encoded."""
        return self._pending is not None or self._encoding >= 0

    def buffer(self) -> np.ndarray:
        """A free (height, width, 3) uint8 image to render the next frame into."""
        with self._cond:
            used = {self._encoding, self._pending[0] if self._pending else -1}
        for index in (0, 1):
            if index not in used:
                return self._images[index]
        raise RuntimeError("FrameEncoder: no free buffer")  # cannot happen: two buffers, one in use at most per role

    def submit(self, image: np.ndarray, seq: int, camera: int, reading_t_ns: int, draft: bool) -> None:
        """Hand over an image returned by buffer(); a frame still waiting is replaced."""
        index = next(i for i, buf in enumerate(self._images) if buf is image)
        with self._cond:
            if self._pending is not None:
                self.dropped += 1
            self._pending = (index, seq, camera, reading_t_ns, draft)
            self._cond.notify()

    def _run(self) -> None:
        import time

        while True:
            with self._cond:
                while self._pending is None and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                index, seq, camera, reading_t_ns, draft = self._pending
                self._pending = None
                self._encoding = index
            start = time.perf_counter_ns()
            jpeg = simplejpeg.encode_jpeg(self._images[index], quality=QUALITY_DRAFT if draft else QUALITY_SHARP,
                                          colorspace="RGB", colorsubsampling="420", fastdct=True)
            self.encode_ns += time.perf_counter_ns() - start
            with self._cond:
                self._encoding = -1
                self.encoded += 1
            self._publish(EncodedFrame(seq, camera, reading_t_ns, draft, jpeg))

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout=5)
