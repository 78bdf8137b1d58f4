"""Takes: crash-safe recording of raw servo readings into MCAP, reading back, and playback.

TakeWriter records Readings (with the rig map and calibration, every record checksummed) so
that a killed process loses nothing written; TakeReader reads them back, recovering every intact
reading of a truncated or damaged take and saying what it skipped (RecoveryReport);
Playback is the one rule that turns a take into timed frames (interpolated ticks, long gaps cut),
shared by play, export, batch, the view and perform; a shot (a take with key poses,
puppet.take.keys) plays its keys, each frame carrying its joints' rotations interpolated in
rotation space (puppet.take.inbetween). The on-disk layout is described in puppet.take.format. Nothing here imports the bus or the native solver.
"""

from puppet.take.background import BackgroundTakeWriter
from puppet.take.errors import TakeError, TakeRigMismatch
from puppet.take.playback import MAX_GAP_S, Cut, Playback
from puppet.take.reader import RecoveryReport, TakeMetadata, TakeReader, check_take_rig
from puppet.take.writer import TakeWriter

__all__ = [
    "BackgroundTakeWriter",
    "Cut",
    "MAX_GAP_S",
    "Playback",
    "RecoveryReport",
    "TakeError",
    "TakeMetadata",
    "TakeReader",
    "TakeRigMismatch",
    "TakeWriter",
    "check_take_rig",
]
