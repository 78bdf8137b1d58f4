"""Optional dynamics: inertia from the previous frames and gravity."""

import numpy as np
import pytest

from puppet.fast import Dynamics, FastError, Pattern


def bent_values(model, helpers, angle):
    pattern = Pattern(full=(0,))
    values = pattern.values()
    values.full[0] = model.rest_T()[:4]
    values.full[0, :3] = helpers.rot_z(angle).T
    return pattern, values


def test_rest_is_an_equilibrium_without_gravity(bar_model):
    pattern = Pattern(full=(0,))
    values = pattern.values()
    values.full[0] = bar_model.rest_T()[:4]
    solver = bar_model.solver(pattern, dynamics=Dynamics(dt=0.05, density=1.0, damping=0.9))
    T = bar_model.rest_T()
    for _ in range(5):
        solver.solve(values, T, iterations=10)
    np.testing.assert_allclose(T, bar_model.rest_T(), atol=1e-5)


def test_gravity_makes_free_parts_sag(bar_model):
    pattern = Pattern(full=(0,))
    values = pattern.values()
    values.full[0] = bar_model.rest_T()[:4]
    g = (0.0, -9.8, 0.0)
    solver = bar_model.solver(pattern, dynamics=Dynamics(dt=0.05, density=0.05, damping=0.5, gravity=g))
    T = bar_model.rest_T()
    for _ in range(10):
        stats = solver.solve(values, T, iterations=10)
    Vd = bar_model.deform(T)
    tip = bar_model.V[:, 0] > 3.5
    sag = (Vd[tip, 1] - bar_model.V[tip, 1]).mean()
    assert sag < -1e-3
    assert np.abs(T[:4] - values.full[0]).max() <= 1e-6  # the constraint still holds
    assert np.isfinite(stats.energy)


def test_inertia_lags_then_catches_up(bar_model, helpers):
    pattern, values = bent_values(bar_model, helpers, 0.6)
    static = bar_model.solver(pattern)
    T_static = bar_model.rest_T()
    static.solve(values, T_static, iterations=200)
    dyn = bar_model.solver(pattern, dynamics=Dynamics(dt=0.05, density=1e-3, damping=0.0))
    T = bar_model.rest_T()
    dyn.solve(values, T, iterations=10, history=True)
    h = dyn.history[1:]
    assert np.all(np.diff(h) <= 1e-6 * bar_model.c0)  # still monotone within a frame
    tipv = int(np.argmax(bar_model.V[:, 0]))
    moved_dyn = np.linalg.norm(bar_model.deform(T)[tipv] - bar_model.V[tipv])
    moved_static = np.linalg.norm(bar_model.deform(T_static)[tipv] - bar_model.V[tipv])
    assert moved_dyn < 0.9 * moved_static  # the first frame lags behind
    for _ in range(100):
        dyn.solve(values, T, iterations=10)
    np.testing.assert_allclose(bar_model.deform(T)[tipv], bar_model.deform(T_static)[tipv], atol=2e-3)


def test_bad_dynamics_are_refused(bar_model):
    for bad in (Dynamics(dt=0.0), Dynamics(damping=2.0), Dynamics(gravity=(0, np.nan, 0)), Dynamics(density=-1)):
        with pytest.raises(FastError, match="dynamics"):
            bar_model.solver(Pattern(full=(0,)), dynamics=bad)
