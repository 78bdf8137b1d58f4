"""Dropout: which bones a silent servo frees, and how many dynamics steps a frame takes, from
the readings' own timestamps (the part of the live solve that knows servos)."""

from __future__ import annotations

import numpy as np

from puppet.fast.live_solve import NOTHING_FREE
from puppet.reading import Reading


class Dropout:
    """Bones to solve free this frame: those of servos whose rig option is ``on_dropout =
    "free"`` and that have been flagged not ok for longer than ``dropout_ms`` (reading time).
    When the servo answers again its bone is sensed again. ``update`` allocates nothing while
    every servo answers."""

    def __init__(self, rig):
        extras = rig.extras
        servos = rig.servo_map.servos
        self._servo_bone = np.array([rig.skeleton.index(s.joint) for s in servos], np.int64)
        self._frees = np.array([extras.dropout_mode(s.id) == "free" for s in servos], bool)
        self.active = bool(self._frees.any())
        self._threshold_ns = int(extras.dropout_ms * 1e6)
        self._last_ok_ns = np.zeros(len(servos), np.int64)
        self._age = np.zeros(len(servos), np.int64)
        self._late = np.zeros(len(servos), bool)
        self._started = False

    def update(self, reading: Reading) -> frozenset:
        """The bones (indices) made free after this reading (NOTHING_FREE mostly)."""
        if not self.active:
            return NOTHING_FREE
        if not self._started:
            self._last_ok_ns[:] = reading.t_ns
            self._started = True
        np.copyto(self._last_ok_ns, reading.t_ns, where=reading.ok)
        np.subtract(reading.t_ns, self._last_ok_ns, out=self._age)
        np.greater(self._age, self._threshold_ns, out=self._late)
        self._late &= self._frees
        if not self._late.any():
            return NOTHING_FREE
        return frozenset(int(b) for b in self._servo_bone[self._late])


class Steps:
    """Dynamics steps per frame: round(elapsed / dt) between two readings, 1..max_steps (always
    1 without dynamics); the same readings give the same steps on every run."""

    def __init__(self, dynamics_options):
        d = dynamics_options
        self.dt_ns = None if d is None else d.dt * 1e9
        self.max_steps = 1 if d is None else d.max_steps
        self._prev_t_ns: int | None = None

    def update(self, t_ns: int) -> int:
        prev, self._prev_t_ns = self._prev_t_ns, t_ns
        if self.dt_ns is None or prev is None:
            return 1
        return int(min(self.max_steps, max(1, round((t_ns - prev) / self.dt_ns))))
