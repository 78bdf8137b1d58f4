"""Playback: the one rule that turns a take into timed frames (``play``, ``export``, ``batch``,
``play --view`` and ``perform`` all ask it).

Time line. Readings keep their recorded spacing, except that a gap between two readings longer
than ``MAX_GAP_S`` is cut to ``MAX_GAP_S`` (a stalled bus, a wrong timestamp: never hours of a
held pose, never billions of frames); every cut is listed in ``cuts`` and ``gap_note`` says it
in words, the same in every command and output. Play time is ns on that time line from the
first reading.

Frames. Frame f (f = 0, 1, ...; an export's frame k is f = k − 1) shows play time
``round(f · speed · 1e9 / fps)`` ns, for every f whose time is at or before the last reading:
frame 0 is the first reading. At speed 0.5 a take gives twice the frames.

Ticks. Each servo's ticks are interpolated linearly between the two readings around the time,
along the shorter way round the encoder (a step of more than half a turn between two readings
is a wrap, never a fast spin; half of each servo's model's ``ticks_per_turn``: 4096 on X and
MX, 1228.8 on AX / RX / XL-320), and rounded to whole ticks. ``ok`` is both neighbours' ok (a
flagged servo's ticks are what the reader recorded: its last good value); a time on a reading
is that reading. Nothing here reads a clock: the frames
are a pure function of the take's timestamps and ticks.

Shots. A shot (a take with keys, ``puppet.take.keys``) plays its keys: key i is at
``(frame_i − 1) / shot fps`` seconds (frames before the first key hold it), no gap is cut (the animator spaced them), and each frame
also carries every joint's rotation (``Reading.rotations``), interpolated in rotation space by
the key's rule (``puppet.take.inbetween``): the sensed joints' constraints of that frame, from
which the FAST solve fills in the free bones. Ticks between keys are interpolated linearly (held
after a "step" key): they are what servos are driven to (``perform``), not what the solve uses.
At the shot's fps and speed 1 frame f is shot frame f + 1, so the frames are the last key's frame.

Clips. ``clip(in_s, out_s)`` is the frames of play times [in_s, out_s] by the same rule (the
take sampled at both ends). A clip played as a loop (``loop=True``, with the rig's
``joint_rotations``) has its seam blended in solve space: each frame carries its joints'
rotations (``Reading.rotations``: the solve is posed from them), and over the clip's last
``loop_blend_s`` (at most half the clip) the rotations are turned, by a smoothstep share of the
seam's rotation per joint, so that the last frame is one step before the first: the clip's last
step per joint, no larger than that joint's median step in the clip. The jump from the last frame
back to the first is then no larger than the clip's median frame-to-frame motion, not the pose's
difference (nor a fast last step's).
"""

from __future__ import annotations

import math
from typing import Iterator, NamedTuple

import numpy as np

from puppet.limits import FPS, SPEED, Range
from puppet.reading import Reading
from puppet.servo_models import MODELS, TICKS_PER_TURN
from puppet.take.errors import TakeError

MAX_GAP_S = 1.0
"""Longest gap between two readings played as recorded, seconds; a longer one plays as this."""
MAX_GAP_NS = int(MAX_GAP_S * 1e9)
LOOP_BLEND_S = 0.5
"""How long before a looping clip's end its seam is blended, seconds (at most half the clip)."""
ROTATION_BLOCK = 256
"""A shot's frames' joint rotations are interpolated this many frames at a time."""


class Cut(NamedTuple):
    """A gap between readings that playback cut to MAX_GAP_S.

    at_ns:  where it starts, ns after the first reading (recorded time).
    gap_ns: its recorded length, ns.
    """

    at_ns: int
    gap_ns: int


def turns_of(models: dict, ids) -> np.ndarray:
    """(k,) ticks per turn of servos ``ids`` by their model names ({id: name}); 4096 for a
    servo whose model is not known."""
    return np.array([getattr(MODELS.get(models.get(int(i))), "ticks_per_turn", TICKS_PER_TURN)
                     for i in ids], float)


def play_times_ns(t_ns: np.ndarray, max_gap_ns: int = MAX_GAP_NS) -> tuple[np.ndarray, list[Cut]]:
    """Play time of each reading and the gaps cut.

    t_ns: (R,) int64 reading times, non-decreasing. Returns ((R,) int64 ns after the first
    reading, every gap cut to max_gap_ns; [Cut] in time order).
    """
    t = np.asarray(t_ns, np.int64)
    gaps = np.diff(t)
    long = np.flatnonzero(gaps > max_gap_ns)
    play = np.zeros(len(t), np.int64)
    np.cumsum(np.minimum(gaps, max_gap_ns), out=play[1:])
    cuts = [Cut(int(t[i] - t[0]), int(gaps[i])) for i in long]
    return play, cuts


class PlayClock:
    """``play_times_ns``'s rule for readings as they come (a live recording's link keys them
    where the take's outputs will put them): ``advance(t_ns)`` -> the reading's play time, ns
    after the first reading, every gap cut to max_gap_ns."""

    def __init__(self, max_gap_ns: int = MAX_GAP_NS) -> None:
        self.max_gap_ns = max_gap_ns
        self.play_ns = 0
        self._last_ns: int | None = None

    def advance(self, t_ns: int) -> int:
        if self._last_ns is not None:
            self.play_ns += min(t_ns - self._last_ns, self.max_gap_ns)
        self._last_ns = t_ns
        return self.play_ns


def gap_note(t_ns: np.ndarray) -> str | None:
    """The warning for a take whose readings at t_ns ((R,) int64) have gaps that playback cuts,
    naming the longest gap and the bound; None when there are none."""
    _, cuts = play_times_ns(t_ns)
    if not cuts:
        return None
    worst = max(cuts, key=lambda c: c.gap_ns)
    return (f"{len(cuts)} gap(s) between readings longer than {MAX_GAP_S:g} s (the longest "
            f"{_seconds(worst.gap_ns * 1e-9)}, {worst.at_ns * 1e-9:.3f} s into the take); "
            f"playback cuts them to {MAX_GAP_S:g} s in every output")


def _seconds(s: float) -> str:
    text = f"{s:.3f} s"
    return text if s < 600 else f"{text} ({s / 3600:.1f} h)"


def check_rate(value, what: str, source, limits: Range = FPS) -> float:
    """value as a float, or TakeError (naming source) unless it is a number within ``limits``
    (puppet.limits.FPS for frames per second, SPEED for a speed factor)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TakeError(source, f"{what} must be a number, got {value!r}") from None
    problem = limits.problem(number)
    if problem is not None:
        raise TakeError(source, f"{what} {problem}")
    return number


class Playback:
    """A take's readings as frames at ``fps`` (see the module docstring for the rule).

    t_ns:  (R,) int64 reading times, non-decreasing, R >= 1.
    ticks: (R, k) int32 continuous encoder counts, one column per servo.
    ok:    (R, k) bool, False where a servo's read failed (its ticks hold the last good value).
    late:  None, or (R, k) bool: True where a servo not ok was only late (``Reading.late``, a
           take of format 3); a frame's servo is late where it is not ok and neither reading
           around it holds a fault. None: every servo not ok counts as at fault.
    ids:   (k,) servo ids, shared by every Reading made.
    ticks_per_turn: (k,) or scalar, each servo's model's (``ServoModel.ticks_per_turn``).
    fps:   frames per second (> 0); speed: take seconds per output second (> 0).
    source: the take file, named in errors.

    Fields: cuts [Cut]; t_ns (R,) recorded times; play_ns (R,) int64 play time of each reading; duration_ns / duration_s
    play time of the last reading; t_first_ns. len() is the frame count, known up front.
    Iterating yields one Reading per frame, stamped t_first_ns + its play time (fresh arrays);
    reading(f) is frame f; at(seconds) the take at any play time (seeking, perform's cycles);
    sample() the same into caller arrays (no allocation); play_s() maps a recorded time.
    """

    def __init__(self, t_ns, ticks, ok, ids, *, fps: float = 30.0, speed: float = 1.0,
                 source="take", interpolation=None, joint_rotations=None,
                 ticks_per_turn=TICKS_PER_TURN, loop: bool = False,
                 loop_blend_s: float = LOOP_BLEND_S, late=None):
        self.source = source
        self.fps = check_rate(fps, "frames per second", source)
        self.speed = check_rate(speed, "speed", source, SPEED)
        t = np.asarray(t_ns, np.int64)
        if t.ndim != 1 or len(t) == 0:
            raise TakeError(source, "the take holds no readings")
        back = np.flatnonzero(np.diff(t) < 0)
        if back.size:
            i = int(back[0]) + 1
            raise TakeError(source, f"reading {i} is timed before reading {i - 1} "
                                    f"({t[i]} < {t[i - 1]} ns): readings must be in time order")
        self.ticks = np.asarray(ticks, np.int64)
        self.ok = np.asarray(ok, bool)
        if self.ticks.shape != (len(t), len(ids)) or self.ok.shape != self.ticks.shape:
            raise TakeError(source, f"ticks {self.ticks.shape} / ok {self.ok.shape} do not fit "
                                    f"{len(t)} readings of {len(ids)} servos")
        self.late = None if late is None else np.asarray(late, bool)
        if self.late is not None and self.late.shape != self.ok.shape:
            raise TakeError(source, f"late {self.late.shape} does not fit ok {self.ok.shape}")
        # (R, k) where a servo's value is held for a fault (not ok, not merely late)
        self._fault = None if self.late is None else ~self.ok & ~self.late
        self.ids = np.asarray(ids)
        self.t_ns = t
        self.t_first_ns = int(t[0])
        self.interpolation = None if interpolation is None else tuple(interpolation)
        if self.interpolation is None:
            self.play_ns, self.cuts = play_times_ns(t)
        else:  # a shot: keys at their frames (t_ns: shot time, frame 1 at 0), nothing cut
            if len(self.interpolation) != len(t):
                raise TakeError(source, f"{len(self.interpolation)} interpolations for "
                                        f"{len(t)} keys")
            if t[0] < 0:
                raise TakeError(source, f"key 0 is timed before frame 1 ({t[0]} ns)")
            self.t_first_ns = 0
            self.play_ns, self.cuts = t.copy(), []
        self._hold = (None if self.interpolation is None else
                      np.array([kind == "step" for kind in self.interpolation]))
        self.duration_ns = int(self.play_ns[-1])
        self.duration_s = self.duration_ns * 1e-9
        self._step_ns = self.speed * 1e9 / self.fps
        count = int(self.duration_ns // self._step_ns) + 1
        while round(count * self._step_ns) <= self.duration_ns:  # guard the float division
            count += 1
        while count > 1 and round((count - 1) * self._step_ns) > self.duration_ns:
            count -= 1
        self._count = count
        k = self.ticks.shape[1]
        self._turn = np.broadcast_to(np.asarray(ticks_per_turn, float), (k,)).copy()
        self._half = self._turn / 2.0
        self._step = np.empty(k, np.float64)  # scratch of sample()
        self._part = np.empty(k, np.float64)
        self._inbetweens = None
        self.layer_notes: list[str] = []
        self.notes: list[str] = []  # what making these frames changed of what was asked (a clip)
        self._loop_rot = None  # (N, b, 3, 3) a looping clip's frames' blended rotations
        self.loop = bool(loop)
        if self.loop:
            if joint_rotations is None or self.interpolation is not None:
                raise TakeError(source, "a loop needs the rig's joint rotations (a take, not "
                                        "a shot)")
            self._loop_rot = self._blended_loop(joint_rotations, loop_blend_s)
        if self.interpolation is not None and joint_rotations is not None:
            from puppet.take.inbetween import Inbetweens

            key_rot = np.stack([joint_rotations(row) for row in self.ticks])  # (K, b, 3, 3)
            self._inbetweens = Inbetweens(self.play_ns, key_rot, self.interpolation)
            self._block_start = 0  # frames [start, start + ROTATION_BLOCK) interpolated ahead
            self._block = None

    def _blended_loop(self, joint_rotations, blend_s: float) -> np.ndarray:
        """(N, b, 3, 3) every frame's joint rotations, the last ``blend_s`` turned toward the
        first frame (the module docstring): R'_f = slerp(I, D, w_f) R_f per joint, D = T R_{N-1}^T
        with T = S^T R_0 the pose one step S before the first frame (S: the last frame's step,
        its angle at most the joint's median step over the clip) and w_f a smoothstep from 0
        (blend start) to 1 (at the last frame, which becomes T)."""
        from scipy.spatial.transform import Rotation

        n = self._count
        k = len(self.ids)
        ticks, ok = np.empty(k, np.int32), np.empty(k, bool)
        rot = []
        for f in range(n):
            self.sample(self.frame_ns(f), ticks, ok)
            rot.append(np.array(joint_rotations(ticks), np.float64))
        rot = np.stack(rot)  # (N, b, 3, 3)
        if n < 3:
            return rot
        b = rot.shape[1]
        steps = Rotation.from_matrix(np.einsum("nbij,nbkj->nbik", rot[1:], rot[:-1])
                                     .reshape(-1, 3, 3)).as_rotvec().reshape(n - 1, b, 3)
        angles = np.linalg.norm(steps, axis=2)                        # (N - 1, b) rad
        most = np.median(angles, axis=0)                              # each joint's median step
        scale = np.minimum(1.0, most / np.maximum(angles[-1], 1e-12))
        step = Rotation.from_rotvec(steps[-1] * scale[:, None]).as_matrix()  # S
        target = np.einsum("bji,bjk->bik", step, rot[0])              # T = S^T R_0
        seam = np.einsum("bij,bkj->bik", target, rot[-1])             # D = T R_{N-1}^T
        frames = max(2, min(int(round(blend_s * self.fps / self.speed)), n // 2))
        start = n - frames  # frame start has w = 0; the last frame has w = 1
        d = Rotation.from_matrix(seam).as_rotvec()
        for f in range(start, n):
            x = (f - start) / (frames - 1)
            w = x * x * (3.0 - 2.0 * x)
            turn = Rotation.from_rotvec(d * w).as_matrix()            # slerp(I, D, w)
            rot[f] = np.einsum("bij,bjk->bik", turn, rot[f])
        return np.ascontiguousarray(rot.reshape(n, b, 3, 3))

    def clip(self, in_s: float, out_s: float, *, loop: bool = False, joint_rotations=None,
             loop_blend_s: float = LOOP_BLEND_S) -> "Playback":
        """The frames of play times [in_s, out_s] (a segment), by this rule; ``loop``: its seam
        blended in solve space (needs the rig's ``joint_rotations(ticks) -> (b, 3, 3)``). An in
        point at or past the take's end is refused; an out point past it ends the clip at the
        end, said in the clip's ``notes``."""
        if self.interpolation is not None:
            raise TakeError(self.source, "a clip is of a take, not of a shot's keys")
        if out_s <= in_s:
            raise TakeError(self.source, f"clip {in_s:g}-{out_s:g} s: the out point must come "
                                         f"after the in point, within {self.duration_s:.3f} s")
        if in_s >= self.duration_s:
            raise TakeError(self.source, f"clip {in_s:g}-{out_s:g} s: the in point is at or past "
                                         f"the take's end, {self.duration_s:.3f} s")
        in_ns = int(round(min(max(in_s, 0.0), self.duration_s) * 1e9))
        out_ns = int(round(min(max(out_s, 0.0), self.duration_s) * 1e9))
        if out_ns <= in_ns:  # within a nanosecond of each other
            raise TakeError(self.source, f"clip {in_s:g}-{out_s:g} s: the out point must come "
                                         f"after the in point, within {self.duration_s:.3f} s")
        k = len(self.ids)
        ends = []
        for at in (in_ns, out_ns):
            ticks, ok, late = np.empty(k, np.int32), np.empty(k, bool), np.empty(k, bool)
            self.sample(at, ticks, ok, late)
            ends.append((ticks, ok, late))
        inside = np.flatnonzero((self.play_ns > in_ns) & (self.play_ns < out_ns))
        t = np.concatenate([[in_ns], self.play_ns[inside], [out_ns]]) + self.t_first_ns
        ticks = np.vstack([ends[0][0], self.ticks[inside], ends[1][0]])
        ok = np.vstack([ends[0][1], self.ok[inside], ends[1][1]])
        late = None if self.late is None else np.vstack([ends[0][2], self.late[inside],
                                                          ends[1][2]])
        clipped = Playback(t, ticks, ok, self.ids, fps=self.fps, speed=self.speed,
                           source=self.source, ticks_per_turn=self._turn, loop=loop,
                           joint_rotations=joint_rotations, loop_blend_s=loop_blend_s,
                           late=late)
        if out_s > self.duration_s + 5e-4:  # past the end by more than the rounding of a time
            clipped.notes.append(f"{self.source}: clip {in_s:g}-{out_s:g} s: the take ends at "
                                 f"{self.duration_s:.3f} s: the clip is {in_s:g}-"
                                 f"{self.duration_s:.3f} s")
        return clipped

    @classmethod
    def of_take(cls, reader, ids, *, fps: float = 30.0, speed: float = 1.0,
                rig=None, layers=None) -> "Playback":
        """The frames of an open TakeReader for the rig servos ``ids`` (its bus order), each
        servo's ticks the short way round its model's turn (the take's models; 4096 where a
        damaged take lost them).

        A shot plays its keys (the module docstring); rig (a ``puppet.rig.Rig``, calibrated as
        the take: its servo map and skeleton) makes its frames carry the joint rotations.
        A layer (``puppet.take.layers``) plays composed over its base, by this same rule;
        ``layers``: its ``LayerOptions`` (mute, solo, punch; None: as recorded);
        ``layer_notes`` then lists what the composition said.
        """
        ids = [int(i) for i in ids]
        keys = reader.keys()
        if keys is not None and keys.keys:
            where = {int(i): n for n, i in enumerate(reader.metadata.ids)}
            reader.check_rig(ids)
            order = np.array([where[i] for i in ids], np.int64)
            rotations = None
            if rig is not None:
                def rotations(ticks):
                    return rig.skeleton.joint_rotations(rig.servo_map.angles(ticks.astype(np.int32)))
            return cls(keys.times_ns(),
                       np.stack([k.ticks[order] for k in keys.keys]),
                       np.stack([k.ok[order] for k in keys.keys]), np.asarray(ids), fps=fps,
                       speed=speed, source=reader.path,
                       interpolation=[k.interpolation for k in keys.keys],
                       joint_rotations=rotations,
                       ticks_per_turn=turns_of(reader.metadata.models, ids))
        if len(reader) == 0:
            raise TakeError(reader.path, "the take holds no readings")
        from puppet.take.layers import compose

        stack = compose(reader, ids, layers)  # a layer over its base; a plain take as recorded
        # a plain take's late replies stay late (a composed layer: every servo not ok, a fault)
        late = reader.late(ids) if reader.metadata.layer is None else None
        playback = cls(stack.t_ns, stack.ticks, stack.ok, np.asarray(ids), fps=fps, speed=speed,
                       source=reader.path, ticks_per_turn=turns_of(reader.metadata.models, ids),
                       late=late)
        playback.layer_notes = stack.notes
        return playback

    def _frame_rotations(self, f: int) -> np.ndarray:
        """(b, 3, 3) joint rotations of frame f of a shot: interpolated ROTATION_BLOCK frames at
        a time (bounded memory whatever the shot's length; no allocation on most frames)."""
        if self._block is None or not self._block_start <= f < self._block_start + ROTATION_BLOCK:
            self._block_start = f
            last = min(f + ROTATION_BLOCK, self._count)
            times = np.rint(np.arange(f, last) * self._step_ns)
            self._block = self._inbetweens.at(times)
        return self._block[f - self._block_start]

    def __len__(self) -> int:
        return self._count

    def frame_ns(self, f: int) -> int:
        """Play time of frame f, ns after the first reading."""
        return int(round(f * self._step_ns))

    def key_frames(self) -> np.ndarray:
        """(K,) int64 the frame nearest each key of a shot (0-based; on the key exactly when the
        key's time is a frame's: at the shot's fps and speed 1, key frame − 1); empty for a take."""
        if self.interpolation is None:
            return np.zeros(0, np.int64)
        return np.minimum(np.rint(self.play_ns / self._step_ns).astype(np.int64), self._count - 1)

    def frame_times_ns(self) -> np.ndarray:
        """(N,) int64 play time of every frame (what the Readings are stamped, less t_first_ns)."""
        return np.rint(np.arange(self._count) * self._step_ns).astype(np.int64)

    def play_s(self, take_t_ns: int) -> float:
        """Play time (seconds) of a recorded take time (a marker), clamped to the take."""
        t, play = self.t_ns, self.play_ns
        i = int(np.searchsorted(t, take_t_ns, side="right")) - 1
        if i < 0:
            return 0.0
        if i >= len(t) - 1:
            return self.duration_s
        return float(play[i] + min(take_t_ns - t[i], play[i + 1] - play[i])) * 1e-9

    def sample(self, play_ns: float, ticks: np.ndarray, ok: np.ndarray,
               late: np.ndarray | None = None) -> None:
        """The take at play time play_ns (ns after the first reading, clamped to the take)
        into ticks ((k,) int32) and ok ((k,) bool), and ``late`` ((k,) bool, when given: False
        everywhere without the take's late mask); allocates nothing."""
        play = self.play_ns
        i = int(np.searchsorted(play, play_ns, side="right")) - 1
        if i < 0:
            i = 0
        if i >= len(play) - 1 or play_ns <= play[i] or (self._hold is not None and self._hold[i]):
            ticks[...] = self.ticks[i]
            ok[...] = self.ok[i]
            if late is not None:
                late[...] = False if self.late is None else self.late[i]
            return
        a = float(play_ns - play[i]) / float(play[i + 1] - play[i])
        step, part = self._step, self._part
        np.subtract(self.ticks[i + 1], self.ticks[i], out=step)  # the short way round
        step += self._half
        np.remainder(step, self._turn, out=step)
        step -= self._half
        np.multiply(step, a, out=part)
        part += 0.5
        np.floor(part, out=part)
        np.add(self.ticks[i], part, out=ticks, casting="unsafe")
        np.logical_and(self.ok[i], self.ok[i + 1], out=ok)
        if late is not None:  # not ok, and no fault on either side: late
            if self._fault is None:
                late[...] = False
            else:
                np.logical_or(self._fault[i], self._fault[i + 1], out=late)
                np.logical_or(late, ok, out=late)
                np.logical_not(late, out=late)

    def at(self, seconds: float) -> Reading:
        """The take at play time ``seconds`` as a Reading (fresh arrays), stamped t_first_ns +
        that play time."""
        play_ns = int(round(seconds * 1e9))
        rotations = None if self._inbetweens is None else self._inbetweens.at([play_ns])[0]
        if self._loop_rot is not None:  # the nearest frame's blended rotations
            rotations = self._loop_rot[min(int(round(play_ns / self._step_ns)), self._count - 1)]
        return self._reading(play_ns, rotations)

    def reading(self, f: int) -> Reading:
        """Frame f (0-based) as a Reading."""
        if not 0 <= f < self._count:
            raise IndexError(f"frame {f} of {self._count}")
        if self._loop_rot is not None:
            return self._reading(self.frame_ns(f), self._loop_rot[f])
        return self._reading(self.frame_ns(f),
                             None if self._inbetweens is None else self._frame_rotations(f))

    def _reading(self, play_ns: int, rotations=None) -> Reading:
        k = len(self.ids)
        ticks, ok = np.empty(k, np.int32), np.empty(k, bool)
        late = None if self.late is None else np.empty(k, bool)
        self.sample(play_ns, ticks, ok, late)
        return Reading(t_ns=self.t_first_ns + play_ns, ids=self.ids, ticks=ticks, ok=ok,
                       rotations=rotations, late=late)

    def __iter__(self) -> Iterator[Reading]:
        for f in range(self._count):
            yield self.reading(f)
