"""Goal positions from a take: recorded ticks at a time (the take's one time rule,
``puppet.take.Playback``: interpolated, long gaps cut; a shot's keys on its time line) -> joint
angles (the take's calibration) -> goal ticks (the performing rig's calibration), clamped,
rate-limited.

A take recorded on one puppet plays on another with its own calibration: the joint angle is
what carries over, ticks -> radians through the take's zero ticks and back to goal ticks through
the rig's (``puppet.servo_models.ServoUnits``: sign, gear, zero, its one wrap rule).
Readings flagged not-ok hold that servo's last good value (the first good one before it).
"""

from __future__ import annotations

import numpy as np

from puppet.drive.errors import DriveError
from puppet.servo_models import ServoUnits
from puppet.take import Playback


class TakeGoals:
    """A take's motion as goal ticks for one rig's servos.

    servos: the rig's servo definitions (rig.servo_map.servos), k of them, in bus order.
    t_ns: (N,) int64 reading times. ticks: (N, k) int32; ok: (N, k) bool.
    take_zero: {id: zero ticks of the recording}; rig_zero: (k,) zero ticks of this rig.

    Attributes: ``duration_s`` (play time: gaps over MAX_GAP_S cut); ``goals`` (N, k) goal ticks
    of each reading; ``flagged`` {id: readings flagged not-ok (held)};
    ``never_ok`` ids with no good reading at all (they hold where they are);
    ``lo``/``hi`` (k,) float goal-tick limits from the rig's joint limits.
    """

    def __init__(self, servos, t_ns: np.ndarray, ticks: np.ndarray, ok: np.ndarray,
                 take_zero: dict[int, int], rig_zero: np.ndarray, interpolation=None) -> None:
        self.ids = np.array([s.id for s in servos], np.int64)
        k = len(self.ids)
        if ticks.shape != (len(t_ns), k) or len(t_ns) == 0:
            raise DriveError(f"take readings shape {ticks.shape} does not fit {k} servos")
        zero_take = np.array([take_zero.get(int(s.id), s.zero_ticks) for s in servos], np.int64)
        self._take_units = ServoUnits.for_servos(servos, zero_take)
        """The take's units (its zero ticks): recorded ticks -> joint radians."""
        self.units = ServoUnits.for_servos(servos, np.asarray(rig_zero, np.int64))
        """The rig's units (its zero ticks): joint radians -> goal ticks."""
        ok = np.asarray(ok, bool)
        self.flagged = {int(i): int(n) for i, n in zip(self.ids, (~ok).sum(axis=0)) if n}
        self.never_ok = [int(i) for i, any_ok in zip(self.ids, ok.any(axis=0)) if not any_ok]
        held = np.array(ticks, np.int32)  # (N, k) the ticks the take's time rule interpolates
        for j in range(k):  # hold the last good value; before the first good one, that one
            good = np.flatnonzero(ok[:, j])
            if len(good) == 0:
                continue
            last = np.maximum.accumulate(np.where(ok[:, j], np.arange(len(ok)), -1))
            last[last < 0] = good[0]
            held[:, j] = held[last, j]
        self._never = ~ok.any(axis=0)
        self.goals = self.units.ticks(self._take_units.angles(held, clamp=False))  # (N, k) float
        self.goals[:, self._never] = np.nan  # NaN: hold
        self.lo, self.hi = self.units.tick_limits()
        self._frames = Playback(t_ns, held, ok, self.ids, interpolation=interpolation,
                                ticks_per_turn=self.units.ticks_per_turn)
        self.duration_s = self._frames.duration_s
        self._ticks, self._ok = np.empty(k, np.int32), np.empty(k, bool)
        self._angles, self._out = np.empty(k), np.empty(k)

    @classmethod
    def from_take(cls, reader, servo_map, key: int | None = None) -> "TakeGoals":
        """Goals for ``servo_map``'s servos from an open TakeReader (refused, TakeRigMismatch,
        when the take's servos or models are not the rig's; RigError naming the take when its
        calibration record is unreadable). key: only that key of a shot (puppet.take.keys),
        one pose held (DriveError naming the take when it is no shot or has no such key)."""
        from puppet.rig.calibration import Calibration  # the parent's side only
        ids = [int(i) for i in servo_map.ids]
        reader.check_rig(ids, dict(servo_map.models))
        interpolation = None
        if key is not None:
            t_ns, ticks, ok = _key_pose(reader, ids, key)
        elif reader.keys() is not None and reader.keys().keys:  # a shot: on its time line
            t_ns, ticks, ok = _key_pose(reader, ids, None)
            interpolation = [k.interpolation for k in reader.keys().keys]
        else:
            t_ns, ticks, ok = reader.arrays(ids=ids)
        if len(t_ns) == 0:
            raise DriveError(f"{reader.path}: the take holds no readings")
        return cls(servo_map.servos, t_ns, ticks, ok,
                   Calibration.from_record(reader.metadata.calibration_text, reader.path).zero_ticks,
                   servo_map.zero, interpolation)

    def degrees(self, ticks) -> np.ndarray:
        """(k,) tick differences -> joint degrees (absolute value)."""
        return self.units.joint_degrees(ticks)

    def at(self, t: float) -> np.ndarray:
        """(k,) goal ticks (float; NaN = hold) at ``t`` seconds of play time into the take: the
        take's ticks there by its time rule (Playback.sample), converted as ``goals``; before
        the start the first reading, after the end the last. Reuses one output array: copy it
        to keep it."""
        self._frames.sample(t * 1e9, self._ticks, self._ok)
        self._take_units.angles(self._ticks, out=self._angles, clamp=False)
        out = self.units.ticks(self._angles, out=self._out)
        out[self._never] = np.nan
        return out


def _key_pose(reader, ids: list[int], key: int | None):
    """(t_ns (K,), ticks (K, k), ok (K, k)) of the keys of the shot open in ``reader`` at their
    times (puppet.take.keys), rig order; key: only that one (K = 1, at 0)."""
    keys = reader.keys()
    if keys is None:
        raise DriveError(f"{reader.path}: not a shot (no keys channel): no key {key} to go to")
    chosen = keys.keys
    if key is not None:  # by its stable id (puppet.take.keys), as every key command
        ids_there = [k.id for k in keys.keys]
        if key not in ids_there:
            raise DriveError(f"{reader.path}: no key {key}: the shot's keys are "
                             + (", ".join(map(str, ids_there)) if ids_there else "none"))
        chosen = [keys.keys[ids_there.index(key)]]
    where = {int(i): n for n, i in enumerate(reader.metadata.ids)}
    order = np.array([where[i] for i in ids], np.int64)
    t_ns = keys.times_ns() if key is None else np.zeros(1, np.int64)
    return (t_ns, np.stack([k.ticks[order] for k in chosen]).astype(np.int32),
            np.stack([k.ok[order] for k in chosen]))


class GoalShaper:
    """Clamp goals to limits and limit their change per cycle; count what it did per servo.

    lo/hi: (k,) goal-tick limits. max_step: (k,) most ticks a goal may move in one cycle.
    ``clamped`` / ``rate_limited``: (k,) int64 cycles in which a servo's goal was changed.
    ``easing``: (k,) bool, servos moving at a slower step after ``ease`` until they get there.
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray, max_step: np.ndarray) -> None:
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.max_step = np.array(max_step, float)
        self._full_step = self.max_step.copy()
        k = len(self.lo)
        self.clamped = np.zeros(k, np.int64)
        self.rate_limited = np.zeros(k, np.int64)
        self.easing = np.zeros(k, bool)
        self._tmp = np.empty(k)
        self.last = np.zeros(k)

    def start(self, present: np.ndarray) -> None:
        """Begin from the servos' present positions."""
        self.last[:] = present

    def ease(self, n: int, present: float, step: float) -> None:
        """Servo ``n`` begins again from ``present`` ticks (e.g. a servo its Bus Watchdog
        stopped), its goal moving at most ``step`` ticks a cycle until it reaches the wanted
        goal; from then on at its own max_step again."""
        self.last[n] = present
        self.max_step[n] = min(step, self._full_step[n])
        self.easing[n] = True

    def shape(self, wanted: np.ndarray) -> np.ndarray:
        """(k,) goal ticks for this cycle from ``wanted`` (NaN = hold the last goal)."""
        tmp = self._tmp
        np.copyto(tmp, wanted)
        hold = np.isnan(tmp)
        tmp[hold] = self.last[hold]
        over = (tmp < self.lo) | (tmp > self.hi)
        self.clamped += over & ~hold
        np.clip(tmp, self.lo, self.hi, out=tmp)
        tmp -= self.last
        fast = np.abs(tmp) > self.max_step
        self.rate_limited += fast & ~self.easing
        np.clip(tmp, -self.max_step, self.max_step, out=tmp)
        self.last += tmp
        if self.easing.any():  # there (not rate-limited this cycle): full speed again
            done = self.easing & ~fast
            self.max_step[done] = self._full_step[done]
            self.easing &= fast
        return self.last
