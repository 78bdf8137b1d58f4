"""Reading: one sample of every servo of a rig (shared by the bus, which makes readings, and the
take, which stores them; it imports neither)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Reading:
    """Present Position of every servo of a rig, read in one group read.

    t_ns:  monotonic timestamp of the read, nanoseconds (time.monotonic_ns()).
    ids:   (k,) int: servo ids, in the rig map's order.
    ticks: (k,) int32: signed, continuous encoder counts (4096 per turn); a failed servo
           holds its last good value.
    ok:    (k,) bool: False where this read failed for that servo.
    late:  None, or (k,) bool: True where a servo's value is held only because its reply came
           late or the line stalled (a ``late_reply``: nothing booked, not a fault); never True
           where ``ok``. None (a take, a shot: the reason was not kept): every servo not ok
           counts as at fault. ``fault_mask`` combines the two.
    rotations: None, or (b, 3, 3) float64 model-space joint rotations of every bone that stand
           for the ticks' (a shot's in-between frame, ``puppet.take.Playback``): the solve's
           sensed-joint constraints come from them instead of the angles.
    """

    t_ns: int
    ids: np.ndarray
    ticks: np.ndarray
    ok: np.ndarray
    rotations: np.ndarray | None = None
    late: np.ndarray | None = None


def fault_mask(reading: Reading, out: np.ndarray) -> np.ndarray:
    """Into ``out`` (k,) bool: True where the servo's value is held because of a fault (not ok,
    and not merely late). Allocates nothing."""
    if reading.late is None:
        return np.logical_not(reading.ok, out=out)
    np.logical_or(reading.ok, reading.late, out=out)
    return np.logical_not(out, out=out)
