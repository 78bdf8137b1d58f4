"""The live solve of a rig: dropout turns sensed bones free (a constraint-pattern switch),
switches are blended, and secondary motion (dynamics) steps at a fixed time step.

    live = LiveSolve(rig, model)                       # when LiveSolve.wanted(rig)
    stats = live.solve(reading.ok, reading.t_ns, angles, T, iterations)   # per frame, T out

Dropout: a servo whose rig option is ``on_dropout = "free"`` and that has been flagged not ok
for longer than ``dropout_ms`` (measured on the readings' own timestamps) makes its bone free:
the solve fills it in. Bones below it that were fully sensed become relative. When the servo
answers again its bone is sensed again. Each switch (either way) is blended over
``blend_frames`` frames: both patterns are solved and T moves linearly (so do the vertices)
from the old pattern's solution to the new one. Patterns are factored on first use and cached:
a servo that flaps never refactors again.

Dynamics: with ``[solver.dynamics]`` every solver is built with inertia and gravity at the
fixed step dt, and a frame takes round(elapsed / dt) steps (1..max_steps), elapsed being the
difference of the readings' timestamps: the same readings (a take) give the same vertices.

Point handles (the live view's dragged surface points): ``set_handles(points, T)`` adds them as
positional constraints to every pattern (a switch, blended like the others; each set of handles
has its own pattern cache), their targets are ``handle_targets`` ((h, 3) float32, set before
each solve). A point is a ``Pattern.positional`` entry: a vertex index or a surface point
((v0, v1, v2), (b0, b1, b2)).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from puppet.fast.factor import positional_rows
from puppet.fast.pattern import Pattern, Values, full_and_relative, positional_entry
from puppet.fast.solver import Dynamics, Solver


NOTHING_FREE: frozenset = frozenset()
"""The base pattern's key: no bone made free."""


@dataclass
class LiveStats:
    """What the last frame did: solver iterations (all steps and patterns) and steps taken."""

    iterations: int = 0
    steps: int = 0
    energy: float = 0.0


class _PatternState:
    """One constraint pattern of the rig (bones in ``free`` made free) with its solver, values
    and warm-start T."""

    def __init__(self, rig, model, free: frozenset, dynamics: Dynamics | None,
                 handles: tuple = ()):
        sk = rig.skeleton
        sensed = rig.sensed.copy()
        sensed[list(free)] = False
        self.free = free
        self.full_bones, self.relative_bones = full_and_relative(sk.parents, sensed)
        self.pattern = Pattern(
            full=tuple(int(j) for j in self.full_bones),
            relative=tuple((int(c), int(sk.parents[c]), tuple(float(x) for x in sk.heads[c]))
                           for c in self.relative_bones),
            positional=tuple(int(v) for v in rig.pins) + handles,
            contacts=tuple((v, axes) for v, axes, _ in rig.contacts),
            limits=rig.limits_for(~sensed),
        )
        start = time.perf_counter()
        self.solver: Solver = model.solver(self.pattern, dynamics=dynamics)
        self.factor_ms = (time.perf_counter() - start) * 1e3
        self.values: Values = self.pattern.values()
        for i, v in enumerate(rig.pins):
            self.values.positional[i] = rig.V[v]
        self.handles = handles
        self.handle_values = self.values.positional[len(rig.pins):]  # (h, 3) view
        for i, (_, _, target) in enumerate(rig.contacts):
            self.values.contact[i] = target
        self.T = model.rest_T()

    def fill(self, rot: np.ndarray, pose: np.ndarray) -> None:
        """This frame's values from the joint rotations (b, 3, 3) and bone poses (b, 3, 4)."""
        for i, j in enumerate(self.full_bones):
            self.values.full[i] = pose[j].T
        for i, j in enumerate(self.relative_bones):
            self.values.relative[i] = rot[j]

    def solve(self, iterations: int, steps: int, stats: LiveStats) -> None:
        for _ in range(steps):
            s = self.solver.solve(self.values, self.T, iterations=iterations)
            stats.iterations += s.iterations
            stats.energy = s.energy


class LiveSolve:
    """Per-frame solve of a rig's readings with dropout switching and dynamics (see module doc).

    Attributes:
        solver:      the base pattern's Solver (every servo sensed, no handles).
        free_bones:  bones made free right now (frozenset of bone indices).
        switches:    pattern switches so far; refactors: patterns factored with the current
                     handles (first use only).
        states:      {frozenset of free bones: pattern} factored with the current handles.
        factor_ms:   {frozenset of free bones: ms} time to factor each of those (the refactor).
        handles:     the points held by point handles (``Pattern.positional`` entries: vertex
                     indices or surface points); handle_targets: (h, 3) float32, model units.
    """

    def __init__(self, rig, model):
        extras = rig.extras
        self.rig, self.model = rig, model
        d = extras.dynamics
        self.dynamics = None if d is None else Dynamics(dt=d.dt, density=d.density, damping=d.damping,
                                                        gravity=d.gravity)
        self.max_steps = 1 if d is None else d.max_steps
        self.dt_ns = None if d is None else d.dt * 1e9
        servos = rig.servo_map.servos
        index = {name: i for i, name in enumerate(rig.skeleton.names)}
        self._servo_bone = np.array([index[s.joint] for s in servos], np.int64)
        self._frees = np.array([extras.dropout_mode(s.id) == "free" for s in servos], bool)
        self._threshold_ns = int(extras.dropout_ms * 1e6)
        self.blend_frames = extras.blend_frames
        self._last_ok_ns = np.zeros(len(servos), np.int64)
        self._age = np.zeros(len(servos), np.int64)
        self._late = np.zeros(len(servos), bool)
        self._prev_t_ns: int | None = None
        b = rig.skeleton.bone_count
        self._rot = np.empty((b, 3, 3))
        self._pose = np.empty((b, 3, 4))
        self._blend = model.rest_T()
        self.handles: tuple = ()
        self.handle_targets = np.zeros((0, 3), np.float32)
        self._caches: dict[tuple, tuple[dict, dict]] = {(): ({}, {})}
        self.states, self.factor_ms = self._caches[()]
        self.current = self._state(NOTHING_FREE)
        self.solver = self.current.solver
        self.free_bones: frozenset = NOTHING_FREE
        self._from: _PatternState | None = None
        self._blend_step = 0
        self.switches = 0
        self.stats = LiveStats()

    @staticmethod
    def wanted(rig) -> bool:
        """True when the rig's options need more than the plain solve (dropout "free", dynamics)."""
        extras = getattr(rig, "extras", None)
        return extras is not None and (extras.frees_on_dropout or extras.dynamics is not None)

    def _state(self, free: frozenset, handles: tuple | None = None) -> _PatternState:
        """The pattern with bones ``free`` made free and ``handles`` (default: the current ones),
        factored on first use (PatternError if the solve would be undetermined or redundant)."""
        handles = self.handles if handles is None else handles
        states, factor_ms = self._caches.get(handles, ({}, {}))
        state = states.get(free)
        if state is None:
            state = _PatternState(self.rig, self.model, free, self.dynamics, handles)
            states[free] = state
            factor_ms[free] = state.factor_ms
            self._caches[handles] = (states, factor_ms)
        return state

    def set_handles(self, points, T: np.ndarray) -> None:
        """Hold these points (``Pattern.positional`` entries: vertex indices or surface points
        ((v0, v1, v2), (b0, b1, b2)); no repeats, none of the rig's pins) at ``handle_targets``,
        which start where the points are in ``T`` (4m, 3); a switch blended from what is shown. A
        PatternError (e.g. a point held only by sensed bones, a malformed point) leaves
        everything as it was."""
        handles = tuple(positional_entry(p, "handles") for p in points)
        new = self._state(self.free_bones, handles)  # factored here: may raise
        model = self.model
        rows = positional_rows(handles, model.V, model.weights64)
        self.handle_targets = (rows @ np.asarray(T, np.float64)).astype(np.float32).reshape(-1, 3)
        self.handles = handles
        self.states, self.factor_ms = self._caches[handles]
        self._switch_to(new, self.free_bones, T)

    @property
    def refactors(self) -> int:
        return len(self.states)

    def _dropped(self, ok: np.ndarray, t_ns: int) -> frozenset:
        if self._prev_t_ns is None:
            self._last_ok_ns[:] = t_ns
        np.copyto(self._last_ok_ns, t_ns, where=ok)
        np.subtract(t_ns, self._last_ok_ns, out=self._age)
        np.greater(self._age, self._threshold_ns, out=self._late)
        self._late &= self._frees
        if not self._late.any():
            return NOTHING_FREE
        return frozenset(int(b) for b in self._servo_bone[self._late])

    def solve(self, ok: np.ndarray, t_ns: int, angles: np.ndarray, T: np.ndarray, iterations: int) -> LiveStats:
        """Solve one reading: ok (k,) bool servo flags, t_ns its timestamp, angles (k,) radians
        (a flagged servo holds its last angle), T (4m, 3) float32 written with the frame's result."""
        stats = self.stats
        stats.iterations = 0
        free = self._dropped(ok, t_ns)
        if free != self.free_bones:
            self._switch(free, T)
        if self.dt_ns is None or self._prev_t_ns is None:
            steps = 1
        else:
            steps = int(min(self.max_steps, max(1, round((t_ns - self._prev_t_ns) / self.dt_ns))))
        self._prev_t_ns = t_ns
        stats.steps = steps
        sk = self.rig.skeleton
        rot = sk.joint_rotations(angles, self._rot)
        pose = sk.pose_from_rotations(rot, self._pose)
        self.current.fill(rot, pose)
        if self.current.handles:
            np.copyto(self.current.handle_values, self.handle_targets)
        self.current.solve(iterations, steps, stats)
        if self._from is None:
            T[...] = self.current.T
            return stats
        self._from.fill(rot, pose)
        self._from.solve(iterations, steps, stats)
        self._blend_step += 1
        a = np.float32(self._blend_step / self.blend_frames)
        np.subtract(self.current.T, self._from.T, out=self._blend)
        self._blend *= a
        np.add(self._from.T, self._blend, out=T)
        if self._blend_step >= self.blend_frames:
            self._from = None
        return stats

    def _switch(self, free: frozenset, T: np.ndarray) -> None:
        """Make ``free`` the current pattern; blend from the old one (started from the shown T)."""
        self._switch_to(self._state(free), free, T)

    def _switch_to(self, new: _PatternState, free: frozenset, T: np.ndarray) -> None:
        old = self.current
        if new is old:
            return
        new.T[...] = T  # warm start from what is on screen
        new.solver.reset_dynamics()
        if self._from is not None and self._from is not new:
            old.T[...] = T  # a switch during a blend: blend on from what is shown
        self._from = old
        self._blend_step = 0
        self.current = new
        self.free_bones = free
        self.switches += 1
