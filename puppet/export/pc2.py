"""PC2 point caches (Blender's Mesh Cache modifier, 3ds Max, Maya): a streaming writer.

Layout, little endian:
  char[12] "POINTCACHE2\\0"; int32 version = 1; int32 numPoints; float32 startFrame;
  float32 sampleRate (frames between samples, 1.0 = one sample per frame); int32 numSamples;
  then numSamples x numPoints x float32[3] (x, y, z).
The vertex order must be the mesh's own vertex order in the DCC tool.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Iterable

import numpy as np

from puppet.export.errors import ExportError
from puppet.export.writer import CountPatchedWriter

PC2_SIGNATURE = b"POINTCACHE2\0"
PC2_HEADER = struct.Struct("<12siiffi")
_NUM_SAMPLES_OFFSET = PC2_HEADER.size - 4


class Pc2Writer(CountPatchedWriter):
    """Writes one sample (all points) at a time; numSamples is patched in at close().

    Memory stays at one sample whatever the take's length. A writer closed by an exception
    (inside `with`) still patches the header, so every sample written is readable.

    path:         output .pc2 file.
    num_points:   n, points (mesh vertices) per sample.
    start_frame:  frame number of the first sample.
    sample_rate:  frames between consecutive samples (1.0: one sample per frame).
    num_samples:  samples written so far.
    """

    def __init__(self, path, num_points: int, *, start_frame: float = 0.0, sample_rate: float = 1.0):
        self.path = Path(path)
        if int(num_points) < 1:
            raise ExportError(self.path, f"num_points must be >= 1, got {num_points}")
        if not (np.isfinite(start_frame) and np.isfinite(sample_rate) and sample_rate > 0):
            raise ExportError(
                self.path, f"bad start_frame={start_frame} / sample_rate={sample_rate} (> 0)"
            )
        self.num_points = int(num_points)
        self.start_frame = float(start_frame)
        self.sample_rate = float(sample_rate)
        self.num_samples = 0
        self._closed = False
        try:
            self._file = open(self.path, "wb")
        except OSError as e:
            raise ExportError(self.path, f"cannot create point cache: {e.strerror}") from e
        self._file.write(
            PC2_HEADER.pack(PC2_SIGNATURE, 1, self.num_points, self.start_frame, self.sample_rate, 0)
        )

    def write(self, points: np.ndarray) -> None:
        """Append one sample. points: (num_points, 3) float, the deformed vertex positions."""
        self._check_open()
        if points.shape != (self.num_points, 3):
            raise ExportError(
                self.path,
                f"sample {self.num_samples}: points have shape {points.shape}, expected "
                f"({self.num_points}, 3)",
            )
        if points.dtype != np.float32 or not points.flags.c_contiguous:
            points = np.ascontiguousarray(points, dtype=np.float32)
        if not np.isfinite(points).all():
            bad = int(np.argwhere(~np.isfinite(points))[0, 0])
            raise ExportError(self.path, f"sample {self.num_samples}: vertex {bad} is not finite")
        self._file.write(memoryview(points).cast("B"))
        self.num_samples += 1

    def _count_field(self) -> tuple[int, bytes]:
        """numSamples' byte offset in the header and its int32 value (patched by close())."""
        return _NUM_SAMPLES_OFFSET, struct.pack("<i", self.num_samples)


def write_pc2(
    path, frames: Iterable[np.ndarray], *, start_frame: float = 0.0, sample_rate: float = 1.0
) -> int:
    """Write an iterable of (n, 3) float32 vertex positions as a PC2 file; returns samples written.

    frames are consumed one at a time (a generator keeps memory at one sample); n comes from
    the first one. An empty iterable is an ExportError (PC2 needs numPoints).
    """
    it = iter(frames)
    first = next(it, None)
    if first is None:
        raise ExportError(path, "no frames to write")
    first = np.asarray(first)
    if first.ndim != 2 or first.shape[1] != 3:
        raise ExportError(path, f"sample 0: points have shape {first.shape}, expected (n, 3)")
    with Pc2Writer(path, first.shape[0], start_frame=start_frame, sample_rate=sample_rate) as w:
        w.write(first)
        for points in it:
            w.write(np.asarray(points))
    return w.num_samples
