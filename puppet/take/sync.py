"""What a take is synchronised to: its sound (content hash, file, offset, rate) and its start
timecode, stored as two optional MCAP metadata records (see puppet.take.format).

  Metadata "puppet.sound"     sha256, name, path, offset_s, rate, channels, frames, crc32
  Metadata "puppet.timecode"  start ("HH:MM:SS:FF", ";FF" at 29.97 drop-frame), rate, crc32

``offset_s`` is the sound's time at the take's time 0 (the first reading): the sound's sample
``round((t + offset_s) · rate)`` plays at take time t; a negative offset starts the sound after
the take. A take without the records (every take before them) has no sound and no timecode.
crc32 is ``puppet.take.format.info_checksum`` of the record's other entries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from puppet import limits
from puppet.take import format as fmt
from puppet.timecode import StartTimecode, TimecodeError

SOUND_METADATA = "puppet.sound"
TIMECODE_METADATA = "puppet.timecode"


@dataclass(frozen=True)
class SoundRef:
    """A take's reference to its sound.

    sha256:   hex SHA-256 of the sound file's bytes (finds and checks the file).
    name:     the file's name; path: where it was when the take was made (absolute).
    offset_s: the sound's time at the take's time 0, seconds.
    rate:     samples per second; channels; frames: samples per channel.
    """

    sha256: str
    name: str
    path: str
    offset_s: float
    rate: int
    channels: int
    frames: int

    def __post_init__(self):
        problem = limits.SOUND_OFFSET.problem(self.offset_s)
        if problem:
            raise ValueError(f"offset_s {problem}")
        if len(self.sha256) != 64 or any(c not in "0123456789abcdef" for c in self.sha256):
            raise ValueError(f"sha256 must be 64 lowercase hex digits, got {self.sha256!r}")
        if int(self.rate) not in limits.SOUND_RATES:
            raise ValueError(f"rate {self.rate} Hz is not one of {limits.SOUND_RATES}")
        if not 1 <= int(self.channels) <= limits.SOUND_CHANNELS_MAX or int(self.frames) < 1:
            raise ValueError(f"{self.channels} channels, {self.frames} frames")

    @property
    def duration_s(self) -> float:
        """Seconds of sound."""
        return self.frames / self.rate

    def to_metadata(self) -> dict[str, str]:
        info = {"sha256": self.sha256, "name": self.name, "path": self.path,
                "offset_s": repr(float(self.offset_s)), "rate": str(int(self.rate)),
                "channels": str(int(self.channels)), "frames": str(int(self.frames))}
        info["crc32"] = fmt.info_checksum(info)
        return info

    @classmethod
    def from_metadata(cls, info: dict[str, str]) -> "SoundRef":
        """The reference in a take's record; ValueError saying what is wrong."""
        check(info)
        offset = float(info["offset_s"])
        if not math.isfinite(offset):
            raise ValueError(f"offset_s {info['offset_s']!r}")
        return cls(sha256=info["sha256"], name=info["name"], path=info["path"], offset_s=offset,
                   rate=int(info["rate"]), channels=int(info["channels"]),
                   frames=int(info["frames"]))


def timecode_metadata(start: StartTimecode) -> dict[str, str]:
    """The "puppet.timecode" record of a start timecode."""
    info = {"start": start.label, "rate": start.rate.name}
    info["crc32"] = fmt.info_checksum(info)
    return info


def timecode_from_metadata(info: dict[str, str]) -> StartTimecode:
    """The start timecode in a take's record; ValueError saying what is wrong."""
    check(info)
    try:
        return StartTimecode(info["start"], info["rate"])
    except TimecodeError as err:
        raise ValueError(str(err)) from None


def check(info: dict[str, str]) -> None:
    """ValueError unless the record's crc32 matches its other entries."""
    if "crc32" not in info:
        raise ValueError("no crc32 entry")
    if fmt.info_checksum(info) != info["crc32"]:
        raise ValueError("checksum mismatch")
