"""Frame sinks: numbered PNG files in a folder, or an MP4 video (H.264 via imageio-ffmpeg).

Both take (height, width, 3) uint8 RGB images, top row first (what Renderer.draw returns),
write each frame as it comes (nothing is buffered in memory), and close on `with` exit.
"""

from pathlib import Path

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np

from puppet.render.errors import SinkError


def _check_frame(image: np.ndarray, size: tuple[int, int] | None, where: str) -> tuple[int, int]:
    """(width, height) of image; raises SinkError unless it is (h, w, 3) uint8 of the given size."""
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        shape = getattr(image, "shape", None)
        dtype = getattr(image, "dtype", None)
        raise SinkError(f"{where}: expected a (height, width, 3) uint8 RGB image, got {dtype} {shape}")
    frame_size = (image.shape[1], image.shape[0])
    if size is not None and frame_size != size:
        raise SinkError(
            f"{where}: frame is {frame_size[0]}x{frame_size[1]}, the sink was opened at {size[0]}x{size[1]}"
        )
    return frame_size


class PngSink:
    """Writes frame_000000.png, frame_000001.png, ... into folder (created if missing).

    pattern: file name with one integer field for the frame number.
    """

    def __init__(self, folder, *, pattern: str = "frame_{:06d}.png"):
        self.folder = Path(folder)
        self.pattern = pattern
        self.count = 0
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise SinkError(f"{self.folder}: cannot create the frame folder: {err}") from err
        self._size = None

    def write(self, image: np.ndarray) -> Path:
        """Write one frame; returns its path. All frames must have the same size."""
        path = self.folder / self.pattern.format(self.count)
        self._size = _check_frame(image, self._size, str(path))
        try:
            iio.imwrite(path, image)
        except OSError as err:
            raise SinkError(f"{path}: cannot write the frame: {err}") from err
        self.count += 1
        return path

    def close(self) -> None:
        """Nothing is held open; kept for symmetry with VideoSink."""

    def __enter__(self) -> "PngSink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class VideoSink:
    """An MP4 file (H.264, yuv420p) at fps frames per second.

    size: (width, height) [px], or None to take it from the first frame; width and height must be
    even (yuv420p). quality: 0 (worst) .. 10 (best), imageio-ffmpeg's scale.
    """

    def __init__(self, path, fps: float = 30.0, *, size: tuple[int, int] | None = None, quality: float = 7.0,
                 codec: str = "libx264"):
        self.path = Path(path)
        if not fps > 0:
            raise SinkError(f"{self.path}: fps must be positive, got {fps}")
        if not self.path.parent.is_dir():
            raise SinkError(f"{self.path}: folder {self.path.parent} does not exist")
        self.fps = float(fps)
        self.quality = float(quality)
        self.codec = codec
        self.count = 0
        self._size = None
        self._writer = None
        self._closed = False
        if size is not None:
            self._open(tuple(int(s) for s in size))

    def _open(self, size: tuple[int, int]) -> None:
        if size[0] % 2 or size[1] % 2 or min(size) < 2:
            raise SinkError(f"{self.path}: video size {size[0]}x{size[1]} must be even in both directions (yuv420p)")
        self._size = size
        self._writer = imageio_ffmpeg.write_frames(
            str(self.path), size, fps=self.fps, quality=self.quality, codec=self.codec,
            pix_fmt_in="rgb24", pix_fmt_out="yuv420p", macro_block_size=1,
        )
        self._writer.send(None)  # start ffmpeg

    def write(self, image: np.ndarray) -> None:
        """Append one frame (height, width, 3) uint8 of the sink's size."""
        if self._closed:
            raise SinkError(f"{self.path}: the sink is closed")
        if self._writer is None:
            self._open(_check_frame(image, None, str(self.path)))
        _check_frame(image, self._size, str(self.path))
        self._writer.send(np.ascontiguousarray(image))
        self.count += 1

    def close(self) -> None:
        """Finish the file (flushes ffmpeg); further writes raise SinkError."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self._closed = True

    def __enter__(self) -> "VideoSink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
