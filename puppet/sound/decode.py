"""Decoding a sound file (WAV, FLAC, OGG Vorbis/Opus, MP3) into a ``Sound`` value.

Decoding is libsndfile's, through the ``soundfile`` package (libsndfile ships inside its
wheels, MP3 included since libsndfile 1.1): no hand-written decoder. A sound is an input: nothing
here writes it, and every command that takes one lists it among its inputs
(``puppet.atomic.check_output``), so no output may overwrite it.

Refused, with a SoundError naming the file: a missing or non-regular file, one libsndfile cannot
decode, an empty one (no samples), one longer than ``puppet.limits.SOUND_SECONDS_MAX``, a rate not
in ``puppet.limits.SOUND_RATES``, more than ``SOUND_CHANNELS_MAX`` channels.
"""

from __future__ import annotations

import hashlib
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet import limits
from puppet.sound.errors import SoundError

#: File name endings ``load_sound`` is meant for (libsndfile sniffs the content, not the name).
SUFFIXES = (".wav", ".flac", ".ogg", ".oga", ".opus", ".mp3", ".aif", ".aiff")


@dataclass(frozen=True, eq=False)
class Sound:
    """A decoded sound.

    path:    the file it was read from (absolute).
    samples: (frames, channels) float32 in [-1, 1], read-only.
    rate:    samples per second per channel (Hz).
    sha256:  hex SHA-256 of the file's bytes.
    """

    path: Path
    samples: np.ndarray = field(repr=False)
    rate: int
    sha256: str

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def frames(self) -> int:
        """Samples per channel."""
        return int(self.samples.shape[0])

    @property
    def channels(self) -> int:
        return int(self.samples.shape[1])

    @property
    def duration_s(self) -> float:
        """Seconds of sound: frames / rate."""
        return self.frames / self.rate


def file_sha256(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes (read in blocks)."""
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def _soundfile():
    try:
        import soundfile
    except OSError as err:  # the wheel's libsndfile could not be loaded
        raise SoundError("soundfile", f"cannot load libsndfile: {err}") from None
    return soundfile


def load_sound(path: str | os.PathLike) -> Sound:
    """Decode a sound file; SoundError naming it when it is refused (see the module docstring)."""
    path = Path(path).absolute()
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise SoundError(path, "no such sound file") from None
    except OSError as err:
        raise SoundError(path, f"cannot open the sound file: {err.strerror or err}") from None
    if not stat.S_ISREG(mode):
        raise SoundError(path, "not a regular file (a sound must be a WAV, FLAC, OGG or MP3 file)")
    if os.path.getsize(path) == 0:
        raise SoundError(path, "empty file, not a sound")
    sf = _soundfile()
    try:
        with sf.SoundFile(path) as f:
            rate, channels, frames = int(f.samplerate), int(f.channels), int(f.frames)
            _check_header(path, rate, channels, frames, f.format)
            samples = f.read(dtype="float32", always_2d=True)
    except (sf.LibsndfileError, RuntimeError, TypeError) as err:
        said = getattr(err, "error_string", None) or str(err)
        # libsndfile says "does not exist" of a file it cannot recognise: it exists (checked above)
        said = "" if "does not exist" in said else f" (libsndfile: {said})"
        raise SoundError(path, f"cannot decode it as a sound: not a WAV, FLAC, OGG or MP3 file "
                               f"libsndfile reads{said}") from None
    if samples.shape[0] == 0:
        raise SoundError(path, "holds no samples (an empty sound)")
    if samples.shape[0] > limits.SOUND_SECONDS_MAX * rate:  # an MP3's frame count is an estimate
        raise SoundError(path, _too_long(samples.shape[0] / rate))
    if not np.isfinite(samples).all():
        raise SoundError(path, "holds samples that are not finite numbers")
    samples.setflags(write=False)
    return Sound(path=path, samples=samples, rate=rate, sha256=file_sha256(path))


def _too_long(seconds: float) -> str:
    return (f"lasts {seconds:.1f} s, over the {limits.SOUND_SECONDS_MAX:g} s a sound may last "
            "(puppet.limits.SOUND_SECONDS_MAX); cut it to the part performed to")


def _check_header(path: Path, rate: int, channels: int, frames: int, kind: str) -> None:
    """Refuse before decoding what the header already shows wrong."""
    if rate not in limits.SOUND_RATES:
        raise SoundError(path, f"sample rate {rate} Hz is not a standard rate "
                               f"({', '.join(map(str, limits.SOUND_RATES))} Hz); resample it")
    if not 1 <= channels <= limits.SOUND_CHANNELS_MAX:
        raise SoundError(path, f"{channels} channels; a sound has 1 to "
                               f"{limits.SOUND_CHANNELS_MAX}")
    if frames == 0:
        raise SoundError(path, f"holds no samples (an empty {kind} sound)")
    if frames > limits.SOUND_SECONDS_MAX * rate * 1.01:  # 1 %: an MP3's header estimate
        raise SoundError(path, _too_long(frames / rate))
