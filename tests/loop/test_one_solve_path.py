"""The one per-frame solve path: the loop's LiveSolve gives what the plain equations give (the
rig's pattern, its values, the solver), and the first frame of every run is converged."""

import numpy as np
import pytest

from puppet.demo import Performance
from puppet.fast.live_solve import COLD_CAP, COLD_TOL
from puppet.loop import Pipeline
from puppet.reading import Reading
from puppet.rig.load import BUILTIN_DYNAMICS_RIG, BUILTIN_RIG, load_rig

FPS = 60.0


def performance(rig, frames, held=False):
    """Readings of the demo's motion at FPS (every one at t = 0 when ``held``: one pose)."""
    perf = Performance(rig)
    ids = rig.servo_map.ids
    out = []
    for f in range(frames):
        t = 0.7 if held else f / FPS
        ticks = np.array([perf.position(i, t) for i in ids]).round().astype(np.int32)
        out.append(Reading(int(f / FPS * 1e9), ids, ticks, np.ones(len(ids), bool)))
    return out


def diagonal(rig) -> float:
    return float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))


def converged(pipeline, reading) -> np.ndarray:
    """(n, 3) vertices of a solve of ``reading`` run far past convergence, with the plain
    equations (the rig's pattern and values, a fresh solver, from rest)."""
    rig, model = pipeline.rig, pipeline.model
    pattern = rig.pattern()
    values = pattern.values()
    rig.fill_values(rig.servo_map.angles(reading.ticks), values)
    T = model.rest_T()
    model.solver(pattern).solve(values, T, iterations=3000, accelerate=False)
    model.solver(pattern).solve(values, T, iterations=3000)
    return model.deform(T)


def test_the_loop_solves_the_plain_equations():
    # The plain path of before (Rig.fill_values + a Solver of rig.pattern()) run by hand with the
    # loop's schedule (a converged first frame, then 8 warm-started iterations a frame) gives
    # the loop's T, frame by frame, on the built-in critter.
    rig = load_rig(BUILTIN_RIG)
    reads = performance(rig, 40)
    with Pipeline(rig, render=False) as pipeline:
        model = pipeline.model
        pattern = rig.pattern()
        assert pipeline.pattern == pattern
        solver, values, T = model.solver(pattern), pattern.values(), model.rest_T()
        worst = 0.0
        for f, reading in enumerate(reads):
            pipeline.solve(reading)
            rig.fill_values(rig.servo_map.angles(reading.ticks), values)
            if f == 0:
                solver.solve(values, T, iterations=COLD_CAP, tol=COLD_TOL)
            else:
                solver.solve(values, T, iterations=8)
            worst = max(worst, float(np.abs(model.deform(pipeline.T) - model.deform(T)).max()))
    assert worst <= 1e-6 * diagonal(rig)


@pytest.mark.parametrize("rig_file", [BUILTIN_RIG, BUILTIN_DYNAMICS_RIG], ids=["plain", "dynamics"])
def test_frame_one_is_converged(rig_file):
    rig = load_rig(rig_file)
    reading = performance(rig, 1, held=True)[0]
    diag = diagonal(rig)
    with Pipeline(rig, render=False) as pipeline:
        reference = converged(pipeline, reading)
        pipeline.solve(reading)
        first = pipeline.deformed()
        assert pipeline.solver_iterations > pipeline.iterations  # it did iterate past the budget
        # The per-frame budget from rest (what frame 1 used to be) is far off: the check can fail.
        T = pipeline.model.rest_T()
        pattern = rig.pattern()
        values = pattern.values()
        rig.fill_values(rig.servo_map.angles(reading.ticks), values)
        pipeline.model.solver(pattern).solve(values, T, iterations=pipeline.iterations)
        assert np.linalg.norm(pipeline.model.deform(T) - reference, axis=1).max() > 1e-2 * diag
    if rig.extras.dynamics is None:
        assert np.linalg.norm(first - reference, axis=1).max() <= 1e-4 * diag
    else:  # gravity sags the free parts: frame 1 is the converged pose of its own energy
        with Pipeline(rig, render=False) as again:
            again.solve(reading)
            again.restart()
            again.solve(reading)
            np.testing.assert_allclose(again.deformed(), first, atol=1e-4 * diag)


def test_restart_solves_cold_again():
    rig = load_rig(BUILTIN_RIG)
    reads = performance(rig, 30)
    with Pipeline(rig, render=False) as pipeline:
        for reading in reads:
            pipeline.solve(reading)
        pipeline.restart()
        before = pipeline.solver_iterations
        pipeline.solve(reads[0])
        assert pipeline.solver_iterations - before > pipeline.iterations
        reference = converged(pipeline, reads[0])
        assert np.linalg.norm(pipeline.deformed() - reference, axis=1).max() <= 1e-4 * diagonal(rig)
