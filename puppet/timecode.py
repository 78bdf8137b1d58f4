"""SMPTE timecode: frame counts <-> HH:MM:SS:FF labels at 23.976, 24, 25, 29.97 drop-frame, 30.

A timecode rate has a frame rate (frames per second, exact: 24000/1001 for 23.976) and a label
base (frames counted per labelled second: 24, 24, 25, 30, 30). Labels count frames in the base;
29.97 drop-frame skips the labels ``:00`` and ``:01`` at the start of every minute except each
tenth minute (no frame is dropped, only labels), so its labels stay within 2 frames of the wall
clock; its separator before the frames is ``;``. 23.976 is non-drop: 24 labels per labelled
second, which runs 1.001 s of real time. Labels wrap at 24 hours.

    rate = timecode_rate("29.97")
    label = frame_to_timecode(17982, rate)      # '00:10:00;00'
    timecode_to_frame(label, rate)              # 17982

A take's start timecode (``StartTimecode``) names the label of its time 0 (the first reading
after the count-in): frame k of a take at the timecode rate (k = 0 at time 0) is labelled
``start + k``; ``--fps`` at the timecode rate and the labels never disagree.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from fractions import Fraction

from puppet.errors import PuppetError


class TimecodeError(PuppetError):
    """A timecode label or rate is not valid (malformed, out of range, a dropped label)."""


@dataclass(frozen=True)
class TimecodeRate:
    """One SMPTE rate.

    name: as written ("23.976", "24", "25", "29.97", "30"); fps: exact frames per second;
    base: frames per labelled second; drop: drop-frame labels (29.97 only).
    """

    name: str
    fps: Fraction
    base: int
    drop: bool

    @property
    def frames_per_day(self) -> int:
        """Labels in 24 hours (where labels wrap)."""
        if self.drop:
            return 24 * 6 * _DF_TEN_MINUTES
        return 24 * 3600 * self.base


_DF_MINUTE = 30 * 60 - 2          # 1798 labels in a minute that drops two
_DF_TEN_MINUTES = 10 * _DF_MINUTE + 2  # 17982 labels every ten minutes

RATES = {
    "23.976": TimecodeRate("23.976", Fraction(24000, 1001), 24, False),
    "24": TimecodeRate("24", Fraction(24), 24, False),
    "25": TimecodeRate("25", Fraction(25), 25, False),
    "29.97": TimecodeRate("29.97", Fraction(30000, 1001), 30, True),
    "30": TimecodeRate("30", Fraction(30), 30, False),
}
"""Every supported rate by name."""

_ALIASES = {"23.98": "23.976", "29.97df": "29.97", "29.97-df": "29.97", "23.976": "23.976"}
_LABEL = re.compile(r"^(\d{2}):(\d{2}):(\d{2})([:;.,])(\d{2})$")


def timecode_rate(rate) -> TimecodeRate:
    """The TimecodeRate of a name ("29.97"), a TimecodeRate, or a number of frames per second
    within 0.001 of one (24000/1001 or 23.976 -> "23.976"); TimecodeError otherwise."""
    if isinstance(rate, TimecodeRate):
        return rate
    if isinstance(rate, str):
        key = _ALIASES.get(rate.strip().lower(), rate.strip())
        if key in RATES:
            return RATES[key]
        try:
            value = float(key)
        except ValueError:
            raise TimecodeError(f"timecode rate {rate!r}: must be one of "
                                f"{', '.join(RATES)}") from None
    else:
        try:
            value = float(rate)
        except (TypeError, ValueError):
            raise TimecodeError(f"timecode rate {rate!r}: must be one of "
                                f"{', '.join(RATES)}") from None
    for r in RATES.values():
        if abs(float(r.fps) - value) < 1e-3:
            return r
    raise TimecodeError(f"timecode rate {rate!r}: must be one of {', '.join(RATES)} frames/s")


def rate_of_fps(fps: float) -> TimecodeRate | None:
    """The timecode rate whose frame rate ``fps`` is (within 0.001), or None."""
    try:
        return timecode_rate(float(fps))
    except TimecodeError:
        return None


def frame_to_timecode(frame: int, rate) -> str:
    """The label of frame number ``frame`` (0 = 00:00:00:00; wraps at 24 hours)."""
    r = timecode_rate(rate)
    frame = int(frame) % r.frames_per_day
    if r.drop:
        tens, rest = divmod(frame, _DF_TEN_MINUTES)
        # every ten-minute block drops 18 labels; within it, each minute after the first drops 2
        frame += 18 * tens + (2 * ((rest - 2) // _DF_MINUTE) if rest >= 2 else 0)
    ff = frame % r.base
    seconds = frame // r.base
    sep = ";" if r.drop else ":"
    return f"{seconds // 3600 % 24:02d}:{seconds // 60 % 60:02d}:{seconds % 60:02d}{sep}{ff:02d}"


def timecode_to_frame(label: str, rate) -> int:
    """The frame number of a label "HH:MM:SS:FF" (";" or ":" before FF); TimecodeError naming
    the label when it is malformed, out of range, or a label drop-frame skips."""
    r = timecode_rate(rate)
    m = _LABEL.match(str(label).strip())
    if m is None:
        raise TimecodeError(f"timecode {label!r}: expected HH:MM:SS:FF")
    hh, mm, ss, sep, ff = int(m[1]), int(m[2]), int(m[3]), m[4], int(m[5])
    if hh > 23 or mm > 59 or ss > 59 or ff >= r.base:
        raise TimecodeError(f"timecode {label!r}: out of range at {r.name} fps (hours 0..23, "
                            f"minutes and seconds 0..59, frames 0..{r.base - 1})")
    if sep in ";," and not r.drop:
        raise TimecodeError(f"timecode {label!r}: ';' marks drop-frame, and {r.name} fps is "
                            "non-drop (write HH:MM:SS:FF)")
    frame = (hh * 3600 + mm * 60 + ss) * r.base + ff
    if r.drop:
        if ss == 0 and ff < 2 and mm % 10 != 0:
            raise TimecodeError(f"timecode {label!r}: drop-frame skips frames 00 and 01 at the "
                                "start of every minute but each tenth")
        minutes = hh * 60 + mm
        frame -= 2 * (minutes - minutes // 10)
    return frame


def seconds_to_frame(seconds: float, rate) -> int:
    """The frame at ``seconds`` since 00:00:00:00 of the frame clock (rounded to the nearest)."""
    r = timecode_rate(rate)
    return round(Fraction(seconds) * r.fps)


@dataclass(frozen=True)
class StartTimecode:
    """The label of a take's time 0 at a rate.

    label: "HH:MM:SS:FF" (";FF" at 29.97); rate: TimecodeRate.
    frame: its frame number; seconds: frame / fps, seconds since 00:00:00:00.
    """

    label: str
    rate: TimecodeRate

    def __post_init__(self):
        object.__setattr__(self, "rate", timecode_rate(self.rate))
        # normalise and check the label (a dropped label or a bad field is refused)
        object.__setattr__(self, "label",
                           frame_to_timecode(timecode_to_frame(self.label, self.rate), self.rate))

    @property
    def frame(self) -> int:
        return timecode_to_frame(self.label, self.rate)

    @property
    def seconds(self) -> float:
        return float(self.frame / self.rate.fps)

    def at(self, k: int) -> str:
        """The label of frame k after time 0 at this rate (k = 0: the start)."""
        return frame_to_timecode(self.frame + int(k), self.rate)

    def later(self, seconds: float) -> "StartTimecode":
        """The label ``seconds`` after this one (the nearest frame at this rate)."""
        return StartTimecode(self.at(round(seconds * self.rate.fps)), self.rate)

    def at_rate(self, rate) -> "StartTimecode":
        """The same start at another rate (the nearest frame of that rate)."""
        r = timecode_rate(rate)
        if r == self.rate:
            return self
        return StartTimecode(frame_to_timecode(round(self.frame / self.rate.fps * r.fps), r), r)

    @classmethod
    def given(cls, label: str, rate) -> "StartTimecode":
        """A start the user gave ("01:00:00:00")."""
        return cls(label, rate)

    @classmethod
    def from_clock(cls, rate, unix_ns: int | None = None) -> "StartTimecode":
        """Time-of-day timecode of ``unix_ns`` (default: now), local time, at the frame before."""
        r = timecode_rate(rate)
        unix_ns = time.time_ns() if unix_ns is None else int(unix_ns)
        seconds, nanos = divmod(unix_ns, 1_000_000_000)
        t = time.localtime(seconds)
        of_day = Fraction(t.tm_hour * 3600 + t.tm_min * 60 + t.tm_sec) + Fraction(nanos, 10**9)
        return cls(frame_to_timecode(int(of_day * r.fps), r), r)
