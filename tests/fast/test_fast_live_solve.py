"""The live solve on the built-in character: dropout frees a silent servo's bones (a cached,
blended pattern switch) and dynamics (secondary motion) lag, settle and replay identically."""

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.demo import Performance
from puppet.loop import Pipeline, run_frames
from puppet.rig import builtin
from puppet.rig.load import BUILTIN_DYNAMICS_RIG, BUILTIN_RIG, load_rig
from puppet.rig.solve_options import DynamicsOptions, SolveExtras

FPS = 60


@pytest.fixture(scope="module")
def rig():
    return builtin()


def readings(rig, frames, *, still_after=None, silent=(), silent_servo=0, jitter=None):
    """The demo performance sampled at FPS: (Reading, ...) with servo ``silent_servo`` flagged
    (holding its last good ticks) on the frames in ``silent``; the motion stops at frame
    ``still_after``; jitter (rng) perturbs the reading times by up to half a frame."""
    perf = Performance(rig)
    ids = np.array([s.id for s in rig.servo_map.servos])
    out, held = [], None
    for f in range(frames):
        t = min(f, still_after if still_after is not None else f) / FPS
        ticks = np.array([perf.position(i, t) for i in ids]).round().astype(np.int32)
        ok = np.ones(len(ids), bool)
        if f in silent:
            ok[silent_servo] = False
            ticks[silent_servo] = held
        held = ticks[silent_servo]
        t_ns = int(f / FPS * 1e9) + (0 if jitter is None else int(jitter.uniform(0, 0.5e9 / FPS)))
        out.append(Reading(t_ns, ids, ticks, ok))
    return out


def solve_all(rig, extras, reads):
    shipped, rig.extras = rig.extras, extras
    out = []
    with Pipeline(rig, render=False) as pipeline:
        M = pipeline.model.lbs_matrix()
        run_frames(pipeline, reads, on_frame=lambda p: out.append(M @ p.T))
        live = pipeline.live
    rig.extras = shipped
    return np.array(out), live


def jumps(V):
    """(frames - 1,) largest per-frame vertex displacement."""
    return np.linalg.norm(np.diff(V, axis=0), axis=2).max(axis=1)


def test_dropout_frees_the_bone_and_blends_both_switches(rig):
    # The puppet stands still; the neck servo goes silent for 30 frames (500 ms) while the
    # puppeteer moves it: it answers again at a new angle.
    reads = readings(rig, 80, still_after=0, silent=range(20, 50))
    for r in reads[50:]:
        r.ticks[0] += 300  # ~26 degrees away from where it was held
    neck = rig.skeleton.names.index("neck")
    hold, _ = solve_all(rig, SolveExtras(), reads)
    free, live = solve_all(rig, SolveExtras(on_dropout="free", blend_frames=6), reads)
    pop, _ = solve_all(rig, SolveExtras(on_dropout="free", blend_frames=1), reads)
    assert live.switches == 2 and live.refactors == 2
    assert set(live.states) == {frozenset(), frozenset({neck})}
    # Held: nothing moves before the servo answers. Freed (after 150 ms = 9 frames): the solve
    # fills the neck in (it moves); sensed again afterwards: the same pose as hold.
    assert np.abs(hold[48] - hold[20]).max() < 1e-4
    switch_in = 29  # first frame past 150 ms of silence (last answer at frame 19)
    assert np.abs(free[switch_in + 8] - hold[switch_in + 8]).max() > 1e-3
    np.testing.assert_allclose(free[-1], hold[-1], atol=1e-4)
    # Blending spreads both switches over frames: the largest per-frame jump at each switch is a
    # fraction of the unblended one.
    for start in (switch_in - 1, 49):
        window = slice(start, start + 8)
        blended, unblended = jumps(free)[window].max(), jumps(pop)[window].max()
        assert blended < 0.5 * unblended, (start, blended, unblended)


def test_a_flapping_servo_reuses_its_patterns(rig):
    # Silent 20 frames, back 5, silent 20, ... : every dropout passes 150 ms, so the pattern
    # switches each time, but only the first switch factors a new pattern.
    silent = [f for f in range(160) if f % 25 < 20 and f >= 10]
    flapping = [f for f in range(160) if f % 2]  # never silent for 150 ms: no switch at all
    _, live = solve_all(rig, SolveExtras(on_dropout="free"), readings(rig, 160, silent=silent))
    assert live.switches >= 10 and live.refactors == 2
    _, live = solve_all(rig, SolveExtras(on_dropout="free"), readings(rig, 160, silent=flapping))
    assert live.switches == 0 and live.refactors == 1
    # A per-servo "hold" override keeps the bone sensed.
    _, live = solve_all(rig, SolveExtras(on_dropout="free", servo_dropout={1: "hold"}),
                        readings(rig, 60, silent=range(10, 60)))
    assert live.switches == 0


def test_dynamics_lag_then_settle_after_the_puppet_stops(rig):
    names = list(rig.skeleton.names)
    ear = int(np.argmax(rig.W[:, names.index("ear_L")] * rig.V[:, 1]))
    reads = readings(rig, 200, still_after=80)
    static, _ = solve_all(rig, SolveExtras(), reads)
    dyn, live = solve_all(rig, SolveExtras(dynamics=DynamicsOptions(density=0.002, dt=1 / FPS)), reads)
    lag = np.linalg.norm(dyn[:, ear] - static[:, ear], axis=1)
    diag = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    assert lag[:81].max() > 0.02 * diag  # the ear lags behind the moving head
    # After the stop, the motion decays: the per-frame change shrinks and the pose settles on
    # the static solve.
    moves = jumps(dyn)[80:]
    assert moves[-20:].max() < 0.05 * moves[:10].max()
    assert lag[-1] < 0.05 * lag[:81].max()
    assert live.stats.steps == 1


def test_the_builtin_dynamics_variant_lags_and_decays(rig):
    """The built-in variant with secondary motion as shipped (critter_dynamics.toml, its
    [solver.dynamics]): the ears lag while the puppet moves; after it stops the motion decays
    and the pose settles on the static solve of the demo's rig (critter.toml, no dynamics)."""
    variant = load_rig(BUILTIN_RIG.with_name("critter_dynamics.toml"))
    assert variant.extras.dynamics is not None and rig.extras.dynamics is None
    assert np.array_equal(variant.V, rig.V) and np.array_equal(variant.W, rig.W)
    names = list(rig.skeleton.names)
    ear = int(np.argmax(rig.W[:, names.index("ear_L")] * rig.V[:, 1]))
    reads = readings(rig, 200, still_after=80)
    static, _ = solve_all(rig, rig.extras, reads)
    dyn, live = solve_all(variant, variant.extras, reads)
    assert live.dynamics is not None
    lag = np.linalg.norm(dyn[:, ear] - static[:, ear], axis=1)
    diag = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    assert lag[:81].max() > 0.01 * diag  # the ear lags behind the moving head
    moves = jumps(dyn)[80:]
    assert moves[-20:].max() < 0.05 * moves[:10].max()
    assert lag[-1] < 0.05 * lag[:81].max()


def test_play_twice_gives_identical_vertices(rig):
    extras = SolveExtras(on_dropout="free", dynamics=DynamicsOptions(density=0.002, dt=1 / 120, max_steps=4))
    reads = readings(rig, 90, silent=range(30, 50), jitter=np.random.default_rng(4))
    first, live = solve_all(rig, extras, reads)
    second, _ = solve_all(rig, extras, reads)
    assert np.array_equal(first, second)
    assert live.stats.steps in (1, 2, 3)  # steps come from the reading times (dt = half a frame)
    assert live.switches == 2


def test_point_handles_join_the_live_solve():
    # The live view's dragged handles (exact surface points) on a rig with dynamics: every
    # pattern gains them.
    rig = load_rig(BUILTIN_DYNAMICS_RIG)
    tail = rig.skeleton.names.index("tail3")
    vertex = int(np.argmax(rig.W[:, tail] * np.linalg.norm(rig.V - rig.skeleton.heads[tail], axis=1)))
    F = np.asarray(rig.F, np.int64)
    corners = tuple(int(v) for v in F[np.flatnonzero((F == vertex).any(axis=1))[0]])
    bary = (0.5, 0.3, 0.2)
    point = (corners, bary)
    reads = readings(rig, 120, still_after=0)
    with Pipeline(rig, render=False) as pipeline:
        live = pipeline.live
        for reading in reads[:10]:
            pipeline.solve(reading)
        assert pipeline.set_handles([point]) > 0
        # The handle starts where the point is: nothing jumps when it is added.
        def where():
            return np.array(bary) @ pipeline.deformed()[list(corners)]
        assert np.linalg.norm(pipeline.handle_targets[0] - where()) < 1e-5
        target = pipeline.handle_targets[0] + np.array([0.0, 0.3, 0.1], np.float32)
        pipeline.handle_targets[0] = target
        for reading in reads[10:60]:
            pipeline.solve(reading)
        assert np.linalg.norm(where() - target) < 1e-4
        blocks = pipeline.T.reshape(-1, 4, 3)
        state = live.current
        assert state.pattern.positional == tuple(int(v) for v in rig.pins) + (point,)
        for q, bone in enumerate(state.pattern.full):  # the sensed bones stay where the servos put them
            assert np.abs(blocks[bone] - state.values.full[q]).max() < 1e-5
        pipeline.set_handles([])
        assert live.current.pattern.positional == tuple(int(v) for v in rig.pins)
        # Cached: the same factored pattern, not a new one (numpy corners and weights are the
        # same point as Python ones).
        pipeline.set_handles([(np.array(corners), np.array(bary))])
        assert live.current is state
