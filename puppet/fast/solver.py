"""The per-pattern FAST solver: a thin facade over the native per-frame iteration."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from puppet import _native
from puppet.fast.blas import one_blas_thread
from puppet.fast.errors import FastError
from puppet.fast.factor import Factor, contact_rows, factor as factor_pattern
from puppet.fast.pattern import Pattern, Values


@dataclass(frozen=True)
class Dynamics:
    """Secondary motion: inertia from the previous frames and gravity (as libigl's with_dynamics).

    The per-frame energy gains (1/dt^2) sum_i m_i |v'_i - p_i|^2 - 2 sum_i m_i g . v'_i, where
    p = M Tp is the inertial prediction Tp = T1 + damping (T1 - T2) from the last two solved poses
    and m_i = density * (lumped vertex area or volume).

    dt:      time step, seconds (larger: weaker inertia).
    density: mass per unit area (surface) or volume (tets), in energy units.
    damping: 0 (no momentum) .. 1 (full momentum).
    gravity: (3,) acceleration, model units / s^2.
    """

    dt: float = 1.0 / 30.0
    density: float = 1e-3
    damping: float = 0.9
    gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def validate(self) -> None:
        g = np.asarray(self.gravity, np.float64)
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise FastError(f"dynamics.dt: {self.dt!r} must be a positive number of seconds")
        if not (np.isfinite(self.density) and self.density >= 0):
            raise FastError(f"dynamics.density: {self.density!r} must be >= 0")
        if not 0.0 <= self.damping <= 1.0:
            raise FastError(f"dynamics.damping: {self.damping!r} must be in [0, 1]")
        if g.shape != (3,) or not np.isfinite(g).all():
            raise FastError(f"dynamics.gravity: {self.gravity!r} must be 3 finite numbers")


class Solver:
    """Per-pattern solver state; create it with :meth:`FastModel.solver`.

    Changing the pattern means a new Solver (a refactor); changing the values does not.
    ``factor``: this pattern's :class:`~puppet.fast.factor.Factor` computed earlier (a shared
    precompute, no dynamics); None computes it here.

    Attributes:
        pattern: the :class:`Pattern` this solver was factored for.
        m:       number of handles (bones + extra weights).
        stats:   native ``SolveStats`` updated in place by every :meth:`solve`
                 (iterations, energy in model units^2, rejected accelerated steps).
    """

    @one_blas_thread()  # the factorization: the same on every machine's thread setting
    def __init__(
        self,
        model,
        pattern: Pattern,
        *,
        anderson_window: int = 5,
        history_capacity: int = 1024,
        dynamics: Dynamics | None = None,
        factor: Factor | None = None,
    ):
        pattern.validate(model.m, model.n)
        self.pattern = pattern
        self.m = model.m
        self.dynamics = dynamics
        Q = model.Q
        if dynamics is not None:
            dynamics.validate()
            Mt, f = model.mass_matrices()
            mass_h2 = dynamics.density * Mt / dynamics.dt**2
            Q = Q + mass_h2
        if factor is None:
            f = factor_pattern(pattern, model.V, model.weights64, Q, model.K)
        elif dynamics is not None or factor.H.shape != (4 * model.m, 4 * model.m):
            raise FastError(f"factor: a shared factor fits a model of {factor.H.shape[0] // 4} "
                            f"handles without dynamics; this solver has {model.m} handles"
                            f"{' and dynamics' if dynamics is not None else ''}")
        else:
            f = factor  # computed once for this pattern elsewhere (batch workers share it)
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
        if dynamics is not None:
            force = dynamics.density * np.outer(model.mass_matrices()[1], np.asarray(dynamics.gravity, np.float64))
            self._native.set_dynamics(
                np.ascontiguousarray(mass_h2, np.float32),
                np.ascontiguousarray(f.H @ mass_h2, np.float32),
                np.ascontiguousarray(f.H @ force, np.float32),
                np.ascontiguousarray(force, np.float32),
                float(dynamics.damping),
            )
        if pattern.contacts:
            self._native.set_contacts(contact_rows(pattern, model.V, model.weights64), pattern.contact_axes())
        if pattern.limits:
            lim = pattern.limits
            self._native.set_limits(
                np.array([c for c, *_ in lim], np.int32),
                np.array([p for _, p, *_ in lim], np.int32),
                np.array([a for _, _, a, *_ in lim], np.float64).reshape(-1, 3),
                np.array([b[3:] for b in lim], np.float64).reshape(-1, 3),
            )
        self._native.set_probes(*model.tolerance_probes())
        self._solve = _native.SolveCall(self._native)  # keeps the last call's arrays, checked once
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
        tol:    None (the default): run exactly ``iterations``. A float > 0: stop as soon as every
                vertex is estimated within tol x the rest mesh's bounding-box diagonal of the
                converged result (tol=1e-4: a tenth of a millimetre on a 1 m character), with
                ``iterations`` the cap. The estimate: the plain step d = G(T) - T measured at a
                few probe vertices (puppet.fast.probes), r = max |M_v d|, times q / (1 - q) for the
                observed contraction rate q (the largest of the last 5: Anderson secants
                |dG| / |dX|, or ratios of successive plain steps; at least the previous tol
                solve's), with a margin of 1.75; the solve then returns that plain step's T
                (a plain step, so inside the joint limits too). Measured on the
                built-in character (bench/solver.py, warm-started demo frames): at tol=1e-4 every
                frame lands within 1e-4 of the diagonal of a converged solve, in fewer iterations
                on average than the fixed budget that keeps every frame there. A tol below what
                float32 reaches (about 1e-5 with acceleration) does not run to the cap: the solve
                stops at the step floor, the first plain step no larger than float32 rounding of
                the vertices (4e-7 x the largest |rest vertex|, at the probes), where more
                iterations no longer move T (the built-in character, rest to a pose, cap 3000:
                tol 1e-5 through 1e-12 all stop after the same 36 accelerated / 326 plain
                iterations); it runs to the cap only where steps never fall to that floor.
        accelerate: Anderson acceleration; a step that would raise the energy (by more than its
                float32 resolution, 1e-6 c0) is rejected for the plain step.
        history: record the energy after every iteration (see :attr:`history`).
        Returns the reused ``stats`` object. Wrong dtype/layout raises TypeError, NaN/inf or
        wrong counts raise ValueError; T is left untouched then.
        """
        if tol is not None and not (np.isfinite(tol) and tol > 0):
            raise FastError(f"solve: tol must be a positive number (a fraction of the bounding-box diagonal) or None, "
                            f"got {tol!r}")
        self._solve(
            values.full,
            values.relative,
            values.positional,
            values.contact,
            T,
            iterations,
            0.0 if tol is None else float(tol),
            accelerate,
            history,
        )
        return self.stats

    def reset_dynamics(self) -> None:
        """Forget the inertia history (after a cut or a jump): the next frame starts at rest."""
        self._native.reset_history()

    @property
    def active_limits(self) -> int:
        """Joint limits projected in the last global step of the last solve."""
        return self._native.active_limits

    @property
    def history(self) -> np.ndarray:
        """(k,) float64 energies of the last solve(history=True): start, then after each iteration."""
        return self._history[: self.stats.history_size]
