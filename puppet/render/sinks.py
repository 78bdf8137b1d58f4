"""Frame sinks: numbered PNG files in a folder, or an MP4 video (H.264 by imageio-ffmpeg's ffmpeg).

Both take (height, width, 3) uint8 RGB images, top row first (what Renderer.draw returns),
write each frame as it comes (the video keeps at most a few frames queued for its encoder),
and close on `with` exit.
"""

import os
import queue
import signal
import shutil
import subprocess
import tempfile
import threading
from fractions import Fraction
from pathlib import Path

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np

from puppet.atomic import commit, flush, temporary_sibling
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


#: Encoder presets (libx264) measured on a 2-core machine, 640x480 demo frames at crf 15, CPU
#: per frame [ms] / file size for 5 s: default (medium) 8.8 / 441 KiB, veryfast 4.2 / 414 KiB,
#: superfast 3.5 / 1027 KiB, ultrafast 2.1 / 1396 KiB. veryfast: half the CPU of the default
#: for the same size (bench/e2e.py), which a live loop on two cores needs.
DEFAULT_PRESET = "veryfast"
ENCODER_MODES = ("thread", "inline")
#: ffmpeg runs at this niceness (through `nice`): the live loop's frames come first.
ENCODER_NICE = 10


class VideoSink:
    """An MP4 file (H.264, yuv420p) at fps frames per second, encoded by an ffmpeg process.

    size: (width, height) [px], or None to take it from the first frame; width and height must be
    even (yuv420p). quality: 0 (worst) .. 10 (best), imageio-ffmpeg's scale (crf = 51 (1 -
    quality / 10) for libx264). preset: libx264 preset (None: ffmpeg's default, 'medium').
    encoder: 'thread' (default): write() copies the frame into one of ``queue_frames``
    preallocated buffers and a thread of its own feeds ffmpeg's pipe, so a full pipe never stalls
    the caller (until every buffer waits: 8 frames, a quarter second at 30 fps, absorb an
    encoder's hiccup; an encoder slower than the frames on average slows the caller down, no
    frame is dropped); 'inline': write() feeds the pipe itself. nice: the encoder's niceness
    (0: as this process): on a machine whose cores the live loop needs, ffmpeg yields to it
    and catches up from its queue.

    The video is written to a temporary file next to ``path`` and renamed to ``path`` when
    ffmpeg has finished it: a failed encoder (killed, disk full) never leaves a half file
    behind, and raises SinkError naming the file on the next write() or on close(). The rename
    is the encoder's own (a shell around ffmpeg, in a session of its own): when this process is
    killed (SIGKILL, a crash), ffmpeg still finishes the frames it was given and ``path`` holds
    that video, playable. ``abort`` kills the encoder first: nothing is renamed.

    sound: a ``puppet.sound.Sound`` muxed in on close (``puppet.sound.mux``): the sound under the
    video, sound_offset_s (the sound's time at the first frame) on, exactly as long as the video;
    a longer sound is cut at its end, said once in ``notes``. The silent video is renamed into
    place first and replaced by the one with sound (a kill in between leaves it silent, playable).
    sound_speed: take seconds per video second (``play --speed``): the sound plays at that speed.
    timecode: a ``puppet.timecode.StartTimecode`` of the first frame: the MP4's timecode track, at
    the video's rate when fps is a timecode rate (else left out, said in ``notes``).
    notes: what the sink did that the user should hear of, in words.
    """

    def __init__(self, path, fps: float = 30.0, *, size: tuple[int, int] | None = None, quality: float = 7.0,
                 codec: str = "libx264", preset: str | None = DEFAULT_PRESET, encoder: str = "thread",
                 queue_frames: int = 8, nice: int = ENCODER_NICE, sound=None,
                 sound_offset_s: float = 0.0, sound_speed: float = 1.0, timecode=None):
        self.path = Path(path)
        if not fps > 0:
            raise SinkError(f"{self.path}: fps must be positive, got {fps}")
        if not self.path.parent.is_dir():
            raise SinkError(f"{self.path}: folder {self.path.parent} does not exist")
        if encoder not in ENCODER_MODES:
            raise SinkError(f"{self.path}: encoder must be one of {ENCODER_MODES}, got {encoder!r}")
        self.fps = float(fps)
        self.quality = float(quality)
        self.codec = codec
        self.preset = "medium" if preset in (None, "default") else preset
        self.encoder = encoder
        self.nice = int(nice)
        self.count = 0
        self._queue_frames = max(1, int(queue_frames))
        self._temporary = temporary_sibling(self.path)
        self._size = None
        self._process = None
        self._log = None
        self._thread = None
        self._error = None       # what went wrong with the encoder (a message), None while fine
        self._reported = False   # the error was raised once already
        self._closed = False
        self.sound, self.sound_offset_s = sound, float(sound_offset_s)
        self.sound_speed = float(sound_speed)
        self.notes: list[str] = []
        self.timecode = self._timecode_label(timecode)
        if size is not None:
            self._open(tuple(int(s) for s in size))

    def _timecode_label(self, timecode) -> str | None:
        """The first frame's label at the video's rate, or None."""
        if timecode is None:
            return None
        from puppet.timecode import rate_of_fps

        rate = rate_of_fps(self.fps)
        if rate is None:
            self.notes.append(f"{self.path}: no timecode track: {self.fps:g} fps is not a "
                              "timecode rate (23.976, 24, 25, 29.97, 30)")
            return None
        return timecode.at_rate(rate).label

    def _command(self, size: tuple[int, int]) -> list[str]:
        crf = int((1 - self.quality / 10.0) * 51)
        quality = ["-crf", str(crf), "-preset", self.preset] if self.codec == "libx264" else []
        nice = ["nice", "-n", str(self.nice)] if self.nice and shutil.which("nice") else []
        # ffmpeg, then (when it succeeded) the rename into place by the encoder's shell: it
        # happens also when this process is gone (paths in the environment, see _open).
        rename = ["sh", "-c", '"$@" && exec mv -f -- "$PUPPET_PARTIAL" "$PUPPET_VIDEO"',
                  "puppet-video-encoder"]
        return [*nice, *rename, imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
                "-s", f"{size[0]}x{size[1]}", "-r", str(Fraction(self.fps).limit_denominator()),
                "-i", "-", "-an", "-vcodec", self.codec, "-pix_fmt", "yuv420p", *quality,
                *(["-timecode", self.timecode] if self.timecode else []),
                "-v", "error", str(self._temporary)]

    def _open(self, size: tuple[int, int]) -> None:
        if size[0] % 2 or size[1] % 2 or min(size) < 2:
            raise SinkError(f"{self.path}: video size {size[0]}x{size[1]} must be even in both directions (yuv420p)")
        self._size = size
        self._log = tempfile.TemporaryFile()
        try:
            # A session of its own: a Ctrl-C in the terminal goes to puppet, which then finishes
            # the video, and not to ffmpeg (which would stop before writing the file's index).
            env = {**os.environ, "PUPPET_PARTIAL": str(self._temporary), "PUPPET_VIDEO": str(self.path)}
            self._process = subprocess.Popen(self._command(size), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                             stderr=self._log, start_new_session=True, env=env)
        except OSError as err:
            raise SinkError(f"{self.path}: cannot start the video encoder: {err}") from err
        if self.encoder == "thread":
            self._free = queue.Queue()
            for _ in range(self._queue_frames):
                self._free.put(np.empty((size[1], size[0], 3), np.uint8))
            self._pending = queue.Queue()
            self._thread = threading.Thread(target=self._pump, name="puppet-video-encoder", daemon=True)
            self._thread.start()

    def _feed(self, frame: np.ndarray) -> bool:
        """Write one frame into ffmpeg's pipe (releases the GIL while it waits); False on failure."""
        try:
            self._process.stdin.write(memoryview(frame).cast("B"))
            return True
        except (BrokenPipeError, OSError, ValueError) as err:
            self._error = self._error or f"the video encoder stopped taking frames ({err})"
            return False

    def _pump(self) -> None:
        """The encoder thread: frames from the pending queue into the pipe, buffers back to the free list."""
        while True:
            frame = self._pending.get()
            if frame is None:
                return
            if self._error is None:
                self._feed(frame)
            self._free.put(frame)

    def _raise_error(self) -> None:
        self._reported = True
        raise SinkError(f"{self.path}: {self._error}{self._ffmpeg_says()}")

    def _ffmpeg_says(self) -> str:
        if self._log is None:
            return ""
        self._log.seek(0)
        text = self._log.read().decode(errors="replace").strip()
        return f"; ffmpeg: {text.splitlines()[-1]}" if text else ""

    def write(self, image: np.ndarray) -> None:
        """Append one frame (height, width, 3) uint8 of the sink's size."""
        if self._closed:
            raise SinkError(f"{self.path}: the sink is closed")
        if self._process is None:
            self._open(_check_frame(image, None, str(self.path)))
        _check_frame(image, self._size, str(self.path))
        if self._error is None and self._process.poll() is not None:
            self._error = f"the video encoder exited (status {self._process.returncode}) before the end"
        if self._error is not None:
            self._raise_error()
        if self._thread is None:
            if not self._feed(np.ascontiguousarray(image)):
                self._raise_error()
        else:
            frame = self._free.get()
            np.copyto(frame, image)
            self._pending.put(frame)
        self.count += 1

    def close(self) -> None:
        """Finish the file: let ffmpeg write its index, then rename it into place. Raises SinkError
        naming the file when the encoder failed (once: a later close does nothing)."""
        if self._closed:
            return
        self._closed = True
        if self._process is None:
            return
        try:
            if self._thread is not None:
                self._pending.put(None)
                self._thread.join()
            try:
                self._process.stdin.close()
            except (BrokenPipeError, OSError) as err:
                self._error = self._error or f"the video encoder stopped taking frames ({err})"
            status = self._process.wait()
            if self._error is None and status != 0:
                self._error = f"the video encoder failed (status {status})"
            if self._error is None:  # the encoder renamed it into place: flush it to disk
                try:
                    flush(self.path)
                except OSError as err:
                    self._error = f"cannot finish the video file: {err}"
            if self._error is not None and not self._reported:
                self._raise_error()
            if self.sound is not None and self.count:
                self._mux_sound()
        finally:
            if self._error is not None:  # the rest of the encoder's session: an ffmpeg whose
                try:  # shell was killed would otherwise write the file after it is removed
                    os.killpg(self._process.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            self._temporary.unlink(missing_ok=True)
            if self._log is not None:
                self._log.close()

    def _mux_sound(self) -> None:
        """Replace the finished silent video by the same video with the sound under it."""
        from puppet.sound.mux import mux_sound
        from puppet.sound.window import cut_at_take_end

        sound, seconds = self.sound, self.count / self.fps
        cut = cut_at_take_end(sound.frames, sound.rate, self.sound_offset_s,
                              seconds * self.sound_speed)
        if cut > 0:
            self.notes.append(f"{sound.path}: the sound is cut at the video's end ({cut:.3f} s "
                              "of it left out)")
        partial = self.path.with_name(f".{self.path.stem}.{os.getpid()}.sound{self.path.suffix}")
        try:
            mux_sound(self.path, partial, sound.samples, sound.rate, self.sound_offset_s, seconds,
                      timecode=self.timecode, source=str(sound.path), speed=self.sound_speed)
            commit(partial, self.path)
        except OSError as err:
            raise SinkError(f"{self.path}: cannot write the video with its sound: {err}; the "
                            "video is kept without sound") from err
        finally:
            partial.unlink(missing_ok=True)

    def abort(self) -> None:
        """Stop the encoder now and remove the unfinished file (nothing is renamed into place)."""
        if self._process is not None and self._process.poll() is None:
            try:  # the encoder's whole session: its shell and ffmpeg (nothing renamed)
                os.killpg(self._process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self._process.wait()
        self._error = self._error or "aborted"
        self._reported = True
        self.close()

    def __enter__(self) -> "VideoSink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
