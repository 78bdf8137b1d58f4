"""The per-pattern FAST solver: a thin facade over the native per-frame iteration."""

from __future__ import annotations

import numpy as np

from puppet import _native
from puppet.fast.factor import factor
from puppet.fast.pattern import Pattern, Values


class Solver:
    """Per-pattern solver state; create it with :meth:`FastModel.solver`.

    Changing the pattern means a new Solver (a refactor); changing the values does not.

    Attributes:
        pattern: the :class:`Pattern` this solver was factored for.
        m:       number of handles (bones + extra weights).
        stats:   native ``SolveStats`` updated in place by every :meth:`solve`
                 (iterations, energy in model units^2, rejected accelerated steps).
    """

    def __init__(self, model, pattern: Pattern, *, anderson_window: int = 5, history_capacity: int = 1024):
        pattern.validate(model.m, model.n)
        self.pattern = pattern
        self.m = model.m
        f = factor(pattern, model.V, model.weights64, model.Q, model.K)
        self.factor = f
        child = np.array([c for c, _, _ in pattern.relative], np.int32)
        parent = np.array([p for _, p, _ in pattern.relative], np.int32)
        self._native = _native.FastSolver(
            model.m,
            model.r,
            len(pattern.full),
            len(pattern.positional),
            len(pattern.relative),
            np.ascontiguousarray(model.K, np.float32),
            np.ascontiguousarray(f.G, np.float32),
            np.ascontiguousarray(f.P2, np.float32),
            np.ascontiguousarray(model.Q, np.float32),
            np.ascontiguousarray(f.H, np.float64),
            float(model.c0),
            child,
            parent,
            anderson_window,
            history_capacity,
        )
        self.stats = self._native.stats
        self._history = self._native.history

    def solve(
        self,
        values: Values,
        T: np.ndarray,
        iterations: int = 10,
        tol: float | None = None,
        accelerate: bool = True,
        history: bool = False,
    ):
        """Run up to ``iterations`` local/global steps, updating T in place (warm start from T).

        values: per-frame targets for this solver's pattern (float32, C-contiguous arrays).
        T:      (4m, 3) float32 C-contiguous; rows 4j..4j+3 hold handle j's transform
                transposed (a rest point p goes to [p 1] @ T[4j:4j+4]).
        tol:    stop early when an iteration lowers the energy by less than tol (relative).
        accelerate: Anderson acceleration; a step that would raise the energy is rejected.
        history: record the energy after every iteration (see :attr:`history`).
        Returns the reused ``stats`` object. Wrong dtype/layout raises TypeError, NaN/inf or
        wrong counts raise ValueError; T is left untouched then.
        """
        self._native.solve(
            values.full,
            values.relative,
            values.positional,
            T,
            iterations,
            0.0 if tol is None else float(tol),
            accelerate,
            history,
        )
        return self.stats

    @property
    def history(self) -> np.ndarray:
        """(k,) float64 energies of the last solve(history=True): start, then after each iteration."""
        return self._history[: self.stats.history_size]
