"""Documented physical ranges of every number a user can give (rig file, command-line option).

A ``Range`` is the one record of a limit: low and high ends (both included unless ``lo_open``),
unit, and whether the number must be an integer. Readers check a value with ``Range.problem``
(None when it fits, else a phrase for the error that names the field); the command line uses
``puppet.cli.common.InRange``, a click type made from a Range. The limits of a rig-file key or an
option are declared beside its documentation (puppet/rig/rig_file.py, solve_options.py, and the
option's help text, which shows the range).

Every number is refused when it is not a number, a bool, nan or infinite, or outside its range;
ranges bound values to what the solver, the bus and memory can take, so nothing absurd but
finite (``dt = 1e300``, a contact at 1e308) gets past loading.
"""

from __future__ import annotations

import math
import numbers
import reprlib
from dataclasses import dataclass

import numpy as np

_show = reprlib.Repr()
_show.maxlevel, _show.maxstring, _show.maxother, _show.maxlist = 2, 40, 40, 4


def _num(x: float) -> str:
    """1000000 rather than 1e+06; 0.0001 and 2147483647 as written."""
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


@dataclass(frozen=True)
class Range:
    """lo..hi in ``unit`` (both ends included; lo excluded when ``lo_open``); ``integer``: whole
    numbers only."""

    lo: float
    hi: float
    unit: str = ""
    integer: bool = False
    lo_open: bool = False

    def __str__(self) -> str:
        kind = "an integer" if self.integer else "a number"
        span = (f"above {_num(self.lo)} up to {_num(self.hi)}" if self.lo_open
                else f"{_num(self.lo)}..{_num(self.hi)}")
        return f"{kind} {span}{' ' + self.unit if self.unit else ''}"

    def holds(self, value) -> bool:
        """Whether value is a number (an integer when ``integer``; numpy scalars too, never a
        bool), finite, inside the range."""
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            return False
        if self.integer and not isinstance(value, numbers.Integral):
            return False
        if not isinstance(value, numbers.Integral) and not math.isfinite(value):
            return False
        if self.lo_open:
            return self.lo < value <= self.hi
        return self.lo <= value <= self.hi

    def problem(self, value) -> str | None:
        """None when value holds, else 'must be <range>, got <value>' (value shown short)."""
        return None if self.holds(value) else f"must be {self}, got {_show.repr(value)}"


def from_environment(name: str, default: float, limit: Range) -> float:
    """The number in environment variable ``name`` (a setting that makes a wait short for tests
    of its mechanism), ``default`` when it is unset or empty. ValueError '<name>=<text>: must be
    <range>, ...' when it is not a number within ``limit``."""
    import os

    text = os.environ.get(name, "")
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = text
    if (problem := limit.problem(value)) is not None:
        raise ValueError(f"{name}={text!r}: {problem} (default {_num(default)})")
    return value


# Command-line options (their help text shows these ranges).
BAUD = Range(9600, 10_500_000, "bit/s", integer=True)
"""Bus speed: Dynamixel baud rates run from 9 600 to 10.5 M bit/s (X series: up to 4.5 M)."""
SPEED = Range(0.01, 100.0, "x")
"""Playback speed factor (1 = as recorded)."""
FPS = Range(0.1, 1000.0, "frames/s")
"""Frames per second of a video, PNG folder or export."""
SECONDS = Range(0.01, 1e6, "s")
"""How long a command runs (about 11 days at most)."""
WATCHDOG_MS = Range(20.0, 2540.0, "ms")
"""Bus Watchdog period (the control table counts 20 ms units up to 127: 2 540 ms)."""
READ_RATE_HZ = Range(1.0, 2000.0, "Hz")
"""Readings per second of the bus reader."""
GOAL_RATE_HZ = Range(1.0, 1000.0, "Hz")
"""Goal writes per second while performing."""
LATENCY_MS = Range(1, 255, "ms", integer=True)
"""USB adapter latency timer (the FTDI timer's range)."""
WORKERS = Range(1, 1024, integer=True)
"""batch: worker processes or CPUs."""
RETRIES = Range(0, 100, integer=True)
"""batch: tries of a take after the first, when its worker died under it."""
FRAME_SIZE = Range(16, 8192, "px", integer=True)
"""Width and height of rendered frames."""
THRESHOLD_DEG = Range(1.0, 90.0, "degrees")
"""Guided calibration: degrees of joint turn a move must reach to count (the same on every
model: each servo's ticks per turn convert it)."""
THRESHOLD_DEG_DEFAULT = 13.0
"""Its default: a deliberate move, far above sensor noise (a few ticks: 0.1° on X-series, 0.3°
on AX), well under the 30° a joint is asked for (``puppet.rig.guided_calibration``)."""
TIMEOUT_S = Range(0.1, 86_400.0, "s")
"""Guided calibration: seconds to wait for each joint."""
ANGLE_DEG = Range(0.0, 180.0, "degrees", lo_open=True)
"""rig axes: the turn shown each way."""
KEYS_DEG = Range(0.0, 90.0, "degrees", lo_open=True)
"""export --keys: how far a reduced glTF rotation curve may stray from the solve."""
KEYS_UNITS = Range(0.0, 1e6, "model units", lo_open=True)
"""export --keys-units: how far a reduced glTF translation curve may stray from the solve."""
KEY_STEP = Range(1, 100_000, "frames", integer=True)
"""keys --step: frames from a key to the next."""
KEY_INDEX = Range(0, 100_000, integer=True)
"""keys delete / goto: a key's index in its shot (0 = the first key)."""
SKIN_INDEX = Range(0, 1_000_000, integer=True)
"""glTF skin index."""
AXES_FROM = Range(1, 3 * 2048, integer=True)
"""rig axes --from: the first turn a sheet shows (three turns a joint, at most puppet.rig.gltf's
MAX_JOINTS = 2048 joints)."""
SHOT_SECONDS = Range(0.0, 3600.0, "s")
"""A shot's length: its last key's time, (frame − 1) / fps. Keys are posed by hand, so an hour is
far beyond any shot (86 401 frames at 24 fps) while everything made from it stays bounded (a
key typed with a few zeros too many is refused, naming it, before export or play runs for
hours); a take's length is bounded by its recording (``record --seconds``, ``SECONDS``)."""
EXPORT_BYTES = Range(0, 16 * 2**30, "bytes", integer=True)
"""The most an export writes to one file without ``--force`` (16 GiB), estimated from the
frames, vertices and joints before anything is written (``puppet.export.run.estimated_bytes``):
a point cache of a long take of a dense mesh grows as frames × vertices × 12 bytes. ``puppet
play --out`` and batch's mp4 follow the same rule (a video frame estimated at
``puppet.export.run.VIDEO_BYTES_PER_PIXEL``), and so do ``puppet play --frames``' PNG frames,
all of them together (``puppet.export.run.PNG_BYTES_PER_PIXEL``)."""

SOUND_SECONDS_MAX = 900.0
"""A sound (--sound FILE) lasts at most 15 minutes: a performance to a voice or a song, and
330 MB decoded at 48 kHz stereo (float32), what a 2-core machine's memory takes beside a render."""
SOUND_RATES = (8000, 11025, 16000, 22050, 24000, 32000, 44100, 48000, 88200, 96000, 176400,
               192000)
"""Sample rates a sound may have (Hz): the standard ones; anything else is refused."""
SOUND_CHANNELS_MAX = 8
"""Channels a sound may have (7.1 at most)."""
COUNT_IN_S = Range(0.0, 60.0, "s")
"""--count-in: seconds counted in before a take's time 0."""
SOUND_OFFSET = Range(-SOUND_SECONDS_MAX, SOUND_SECONDS_MAX, "s")
"""--sound-offset: the sound's time at the take's time 0 (negative: the sound starts after it)."""

# Session folders (puppet.studio): what one index holds, bounded so that it stays a file a person
# can read and the page can list at once.
SESSION_TAKES = 10_000
"""Takes in one session folder, trashed ones included (a take's number is never reused)."""
SESSION_SHOTS = 1_000
"""Shots in one session folder."""
TAKE_NUMBER = Range(1, SESSION_TAKES, integer=True)
"""A take's number within its shot (take 1 is the shot's first recording)."""
NOTE_CHARS = 2_000
"""Characters of a take's note."""
NAME_CHARS = 80
"""Characters of a shot's or a segment's name."""
SEGMENTS_PER_TAKE = 100
"""Segments (named in/out clips) of one take."""
INDEX_BYTES = 32 * 1024 * 1024
"""Size of a session's index file (10 000 takes with notes and segments fit); a larger file is
not read: it is treated as damaged and rebuilt from the takes."""
SESSION_FREE_BYTES = 16 * 1024 * 1024
"""Free space a session folder's disk must have before a recording starts (about four minutes of
15 servos read at 500 Hz: 131 bytes a reading)."""
SECONDS_FROM_START = Range(0.0, 1e6, "s")
"""A point in a take: seconds from its first reading (a segment's in and out)."""
