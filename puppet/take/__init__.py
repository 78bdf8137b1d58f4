"""Takes: crash-safe recording of raw servo readings into MCAP, reading back, and playback.

TakeWriter records Readings (with the rig map and calibration) so that a killed process loses
nothing written; TakeReader reads them back, recovering a truncated tail; PlaybackClock turns
them into frames at a fixed rate. The on-disk layout is described in puppet.take.format.
"""

from puppet.take.background import BackgroundTakeWriter
from puppet.take.errors import TakeError, TakeRigMismatch
from puppet.take.playback import PlaybackClock, PlaybackFrame, pace
from puppet.take.reader import TakeMetadata, TakeReader, check_take_rig
from puppet.take.writer import TakeWriter

__all__ = [
    "BackgroundTakeWriter",
    "PlaybackClock",
    "PlaybackFrame",
    "TakeError",
    "TakeMetadata",
    "TakeReader",
    "TakeRigMismatch",
    "TakeWriter",
    "check_take_rig",
    "pace",
]
