"""LiveSolve: the one per-frame FAST solve. A family of constraint patterns (which handles are
free this frame), blended switches between them, point handles, secondary motion, and a
converged first frame. Arrays and patterns in, transforms out: it knows nothing of servos.

    live = LiveSolve(model, rig.pattern, contact_targets=...)     # the plain case: one pattern
    stats = live.solve(free, rot, pose, T, iterations, steps)     # per frame, T out

free:  frozenset of handles made free this frame (NOTHING_FREE: the base pattern). The caller
       decides (a silent servo's bones, see puppet.loop.dropout); ``patterns(free)`` gives the
       pattern. Each pattern is factored on first use and cached: a flapping choice never
       refactors again. The base pattern without handles may come factored (a shared
       ``RigPrecompute``'s factor).
Switch: when ``free`` or the handles change, both the old and the new pattern are solved for
       ``blend_frames`` frames and T moves linearly (so do the vertices) from the old pattern's
       solution to the new one.
Dynamics: with ``dynamics`` every solver carries inertia and gravity at the fixed step dt; a
       frame takes ``steps`` steps (the caller counts them from the readings' times).
Cold start: the first frame (and the first after ``restart()``) iterates to the tolerance stop
       (COLD_TOL of the bounding-box diagonal, at most COLD_CAP iterations) instead of the
       per-frame budget, so frame 1 of every run is a converged pose; later frames warm-start.
Point handles (the live view's dragged surface points): ``set_handles(points, T)`` adds them as
       positional constraints to every pattern (a switch, blended like the others); their targets
       are ``handle_targets`` ((h, 3) float32, set before each solve).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from puppet.fast.factor import Factor, positional_rows
from puppet.fast.pattern import Pattern, PoseFill, Values, positional_entry, rest_positions
from puppet.fast.solver import Dynamics, Solver

NOTHING_FREE: frozenset = frozenset()
"""The base pattern's key: no handle made free."""
COLD_TOL = 1e-5
"""The first frame's tolerance stop, a fraction of the rest bounding-box diagonal (see
Solver.solve's ``tol``): every vertex within it of the converged pose."""
COLD_CAP = 2000
"""Most iterations the first frame may take (an ill-conditioned rig stops here)."""


@dataclass
class LiveStats:
    """What the last frame did: solver iterations (all steps and patterns), steps taken, the
    last energy, and the nanoseconds spent in the native iterations themselves."""

    iterations: int = 0
    steps: int = 0
    energy: float = 0.0
    iterate_ns: int = 0


class _PatternState:
    """One pattern (``free`` handles made free, ``handles`` held) with its solver, values,
    pose fill and warm-start T."""

    def __init__(self, model, pattern: Pattern, free: frozenset, handles: tuple,
                 contact_targets: np.ndarray, dynamics: Dynamics | None, factor: Factor | None):
        start = time.perf_counter()
        self.solver: Solver = model.solver(pattern, dynamics=dynamics, factor=factor)
        self.factor_ms = (time.perf_counter() - start) * 1e3
        self.pattern, self.free, self.handles = pattern, free, handles
        self.values: Values = pattern.values()
        pins = len(pattern.positional) - len(handles)
        self.values.positional[:pins] = rest_positions(pattern.positional[:pins], model.V)
        self.values.contact[:] = contact_targets
        self.handle_values = self.values.positional[pins:]  # (h, 3) view
        self.fill = PoseFill(pattern)
        self.T = model.rest_T()

    def solve(self, iterations: int, steps: int, stats: LiveStats, tol: float | None = None) -> None:
        for _ in range(steps):
            start = time.perf_counter_ns()
            s = self.solver.solve(self.values, self.T, iterations=iterations, tol=tol)
            stats.iterate_ns += time.perf_counter_ns() - start
            stats.iterations += s.iterations
            stats.energy = s.energy


class LiveSolve:
    """The per-frame solve over a family of patterns (see the module doc).

    model:           the FastModel.
    patterns:        free handles (frozenset) -> Pattern without point handles (e.g. Rig.pattern).
    contact_targets: (c, 3) targets of the patterns' contacts (only their axes are read).
    dynamics:        Dynamics or None. blend_frames: frames a switch is blended over (>= 1).
    factor:          the base pattern's Factor computed earlier (no dynamics), or None.

    Attributes: free_bones (the current key), handles, handle_targets ((h, 3) float32),
    switches (so far), states / factor_ms ({free: state / ms to factor} with the current
    handles), stats (LiveStats of the last frame); solver, pattern, values of the current pattern.
    """

    def __init__(self, model, patterns: Callable[[frozenset], Pattern], *,
                 contact_targets=(), dynamics: Dynamics | None = None, blend_frames: int = 1,
                 factor: Factor | None = None):
        self.model, self.patterns = model, patterns
        self.contact_targets = np.asarray(contact_targets, np.float32).reshape(-1, 3)
        self.dynamics = dynamics
        self.blend_frames = max(1, int(blend_frames))
        self._factor = factor if dynamics is None else None
        self._blend = model.rest_T()
        self.handles: tuple = ()
        self.handle_targets = np.zeros((0, 3), np.float32)
        self._caches: dict[tuple, tuple[dict, dict]] = {(): ({}, {})}
        self.states, self.factor_ms = self._caches[()]
        self.current = self._state(NOTHING_FREE)
        self.free_bones: frozenset = NOTHING_FREE
        self._from: _PatternState | None = None
        self._blend_step = 0
        self._cold = True
        self.switches = 0
        self.stats = LiveStats()

    @property
    def solver(self) -> Solver:
        return self.current.solver

    @property
    def pattern(self) -> Pattern:
        return self.current.pattern

    @property
    def values(self) -> Values:
        return self.current.values

    @property
    def refactors(self) -> int:
        return len(self.states)

    def _state(self, free: frozenset, handles: tuple | None = None) -> _PatternState:
        """The pattern with handles ``free`` made free and ``handles`` (default: the current
        ones), factored on first use (PatternError if undetermined or redundant)."""
        handles = self.handles if handles is None else handles
        states, factor_ms = self._caches.get(handles, ({}, {}))
        state = states.get(free)
        if state is None:
            base = self.patterns(free)
            pattern = base if not handles else Pattern(
                full=base.full, relative=base.relative, positional=base.positional + handles,
                contacts=base.contacts, limits=base.limits)
            factor = self._factor if not free and not handles else None
            state = _PatternState(self.model, pattern, free, handles, self.contact_targets,
                                  self.dynamics, factor)
            states[free] = state
            factor_ms[free] = state.factor_ms
            self._caches[handles] = (states, factor_ms)
        return state

    def restart(self) -> None:
        """The next frame starts cold (from rest, iterated to convergence): after a cut."""
        self._cold = True
        self._from = None

    def set_handles(self, points, T: np.ndarray) -> None:
        """Hold these points (``Pattern.positional`` entries: vertex indices or surface points
        ((v0, v1, v2), (b0, b1, b2)); no repeats, none of the patterns' own) at
        ``handle_targets``, which start where the points are in ``T`` (4m, 3); a switch blended
        from what is shown. A PatternError (a point held only by sensed handles, a malformed
        point) leaves everything as it was."""
        handles = tuple(positional_entry(p, "handles") for p in points)
        new = self._state(self.free_bones, handles)  # factored here: may raise
        model = self.model
        rows = positional_rows(handles, model.V, model.weights64)
        self.handle_targets = (rows @ np.asarray(T, np.float64)).astype(np.float32).reshape(-1, 3)
        self.handles = handles
        self.states, self.factor_ms = self._caches[handles]
        self._switch_to(new, self.free_bones, T)

    def solve(self, free: frozenset, rot: np.ndarray, pose: np.ndarray, T: np.ndarray,
              iterations: int, steps: int = 1) -> LiveStats:
        """Solve one frame into T ((4m, 3) float32, written).

        free: handles made free this frame; rot: (b, 3, 3) model-space joint rotations; pose:
        (b, 3, 4) bone affines (forward kinematics of the same angles); iterations: the
        per-frame budget (warm-started); steps: dynamics steps this frame (1 without dynamics).
        """
        stats = self.stats
        stats.iterations = stats.iterate_ns = 0
        stats.steps = steps
        if free != self.free_bones:
            self._switch_to(self._state(free), free, T)
        current = self.current
        current.fill.fill(current.values, rot, pose)
        if current.handles:
            np.copyto(current.handle_values, self.handle_targets)
        if self._cold:
            self._cold = False
            current.solver.reset_dynamics()
            current.T[...] = self.model.rest_T()
            current.solve(COLD_CAP, 1, stats, tol=COLD_TOL)
            T[...] = current.T
            return stats
        current.solve(iterations, steps, stats)
        if self._from is None:
            T[...] = current.T
            return stats
        old = self._from
        old.fill.fill(old.values, rot, pose)
        old.solve(iterations, steps, stats)
        self._blend_step += 1
        a = np.float32(self._blend_step / self.blend_frames)
        np.subtract(current.T, old.T, out=self._blend)
        self._blend *= a
        np.add(old.T, self._blend, out=T)
        if self._blend_step >= self.blend_frames:
            self._from = None
        return stats

    def _switch_to(self, new: _PatternState, free: frozenset, T: np.ndarray) -> None:
        """Make ``new`` the current pattern; blend from the old one (started from the shown T)."""
        old = self.current
        if new is old:
            return
        new.T[...] = T  # warm start from what is on screen
        new.solver.reset_dynamics()
        if self._from is not None and self._from is not new:
            old.T[...] = T  # a switch during a blend: blend on from what is shown
        self._from = None if self._cold else old
        self._blend_step = 0
        self.current = new
        self.free_bones = free
        self.switches += 1
