"""Positional constraints on surface points: ((v0, v1, v2), (b0, b1, b2)) holds the barycentric
combination sum_k b_k V'[v_k] of a triangle's corners (the live view's exact point handles)."""

import numpy as np
import pytest

from puppet.demo import Performance
from puppet.fast import Pattern, PatternError
from puppet.fast.factor import constraint_rows
from puppet.bus import Reading
from puppet.loop import Pipeline
from puppet.rig.load import BUILTIN_DYNAMICS_RIG, BUILTIN_RIG, load_rig

FPS = 60


def reference_lbs_matrix(V, W):
    """(n, 4m) M with V' = M T built entry by entry: M[i, 4j + c] = W[i, j] [V_i 1]_c."""
    n, m = W.shape
    M = np.zeros((n, 4 * m))
    for j in range(m):
        for c in range(3):
            M[:, 4 * j + c] = W[:, j] * V[:, c]
        M[:, 4 * j + 3] = W[:, j]
    return M


def tail_point(rig):
    """A surface point on the tail tip's triangle: its corners and uneven barycentric weights."""
    tail = rig.skeleton.names.index("tail3")
    vertex = int(np.argmax(rig.W[:, tail] * np.linalg.norm(rig.V - rig.skeleton.heads[tail], axis=1)))
    F = np.asarray(rig.F, np.int64)
    triangle = int(np.flatnonzero((F == vertex).any(axis=1))[0])
    return tuple(int(v) for v in F[triangle]), (0.2, 0.5, 0.3)


def performance(rig, frames):
    perf = Performance(rig)
    ids = np.array([s.id for s in rig.servo_map.servos])
    out = []
    for f in range(frames):
        ticks = np.array([perf.position(i, f / FPS) for i in ids]).round().astype(np.int32)
        out.append(Reading(int(f / FPS * 1e9), ids, ticks, np.ones(len(ids), bool)))
    return out


@pytest.mark.parametrize("rig_file", [BUILTIN_RIG, BUILTIN_DYNAMICS_RIG], ids=["plain", "dynamics"])
def test_a_point_handle_holds_the_exact_surface_point(rig_file):
    rig = load_rig(rig_file)
    corners, bary = tail_point(rig)
    b = np.array(bary)
    diag = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    reads = performance(rig, 70)
    with Pipeline(rig, render=False) as pipeline:
        assert (pipeline.live.dynamics is not None) == (rig_file == BUILTIN_DYNAMICS_RIG)
        for reading in reads[:10]:
            pipeline.solve(reading)
        assert pipeline.set_handles([(corners, bary)]) > 0
        # The handle starts where its point is: nothing jumps when it is added.
        start = b @ pipeline.deformed()[list(corners)]
        assert np.linalg.norm(pipeline.handle_targets[0] - start) < 1e-6 * diag
        target = (start + np.array([0.0, 0.15, 0.1]) * diag).astype(np.float32)
        pipeline.handle_targets[0] = target
        for reading in reads[10:]:
            pipeline.solve(reading)
        point = b @ pipeline.deformed()[list(corners)]
        assert np.linalg.norm(point - target) < 1e-4 * diag
        # The sensed bones stay where the servos put them (forward kinematics).
        blocks = pipeline.T.reshape(-1, 4, 3)
        full_bones, full = pipeline.pattern.full, pipeline.values.full
        pose = rig.pose(pipeline.angles)
        for q, bone in enumerate(full_bones):
            np.testing.assert_allclose(full[q], pose[bone].T, atol=1e-6)
            assert np.abs(blocks[bone] - full[q]).max() < 1e-5
        pipeline.set_handles([])
        assert pipeline.pattern.positional == tuple(int(v) for v in rig.pins)


def test_point_rows_match_an_independent_reference(bar_model):
    model = bar_model
    M = reference_lbs_matrix(model.V, model.weights64)
    tip = int(np.argmax(model.V[:, 0]))
    points = (((3, 17, 40), (0.25, 0.25, 0.5)), tip, ((100, 101, 120), (0.6, 0.3, 0.1)))
    pattern = Pattern(full=(0,), positional=points)
    A = constraint_rows(pattern, model.V, model.weights64)
    assert A.shape == (4 + 3, 4 * model.m)
    np.testing.assert_array_equal(A[:4, :4], np.eye(4))
    expected = [0.25 * M[3] + 0.25 * M[17] + 0.5 * M[40], M[tip], 0.6 * M[100] + 0.3 * M[101] + 0.1 * M[120]]
    np.testing.assert_allclose(A[4:], np.array(expected), rtol=0, atol=1e-14)
    # row @ T is the point on the deformed mesh, for any T.
    T = np.random.default_rng(2).normal(size=(4 * model.m, 3))
    deformed = model.deform(T)
    np.testing.assert_allclose(A[4] @ T, 0.25 * deformed[3] + 0.25 * deformed[17] + 0.5 * deformed[40], atol=1e-12)


def test_a_point_on_one_corner_solves_as_that_vertex(bar_model):
    model = bar_model
    tip = int(np.argmax(model.V[:, 0]))
    T = {}
    for name, entry in (("vertex", tip), ("point", ((tip, 5, 9), (1.0, 0.0, 0.0)))):
        pattern = Pattern(full=(0,), relative=((1, 0, (4.0 / 3, 0, 0)),), positional=(entry,))
        solver = model.solver(pattern)
        values = pattern.values()
        values.full[0] = model.rest_T()[:4]
        values.positional[0] = (model.V[tip] + np.array([-0.6, 1.2, 0.3])).astype(np.float32)
        T[name] = model.rest_T()
        solver.solve(values, T[name], iterations=30)
    assert np.array_equal(T["point"], T["vertex"])
    assert np.abs(T["vertex"] - model.rest_T()).max() > 0.1  # the pin really moved the bar


@pytest.mark.parametrize("entry, problem", [
    (((0, 1, 10**7), (0.2, 0.3, 0.5)), r"pattern.positional\[1\] \(point \(0, 1, 10000000\), .*corner vertex 10000000 is not in 0\.\."),
    (((0, 1, -1), (0.2, 0.3, 0.5)), r"pattern.positional\[1\] \(point \(0, 1, -1\), .*corner vertex -1 is not in 0\.\."),
    (((0, 1, 2), (0.2, float("nan"), 0.8)), r"pattern.positional\[1\] \(point \(0, 1, 2\), \(0.2, nan, 0.8\)\): barycentric weights must be finite"),
    (((0, 1, 2), (0.2, 0.3, 0.6)), r"pattern.positional\[1\] \(point \(0, 1, 2\), \(0.2, 0.3, 0.6\)\): barycentric weights sum to 1.1"),
    (((0, 1, 2), (0.2, 0.8)), r"pattern.positional\[1\]: \(\(0, 1, 2\), \(0.2, 0.8\)\) is neither a vertex index nor a surface point"),
    (((0.5, 1, 2), (0.2, 0.3, 0.5)), r"pattern.positional\[1\]: .* is neither a vertex index nor a surface point"),
    ("corner", r"pattern.positional\[1\]: 'corner' is neither a vertex index nor a surface point"),
    (((7, 0, 1), (1.0, 0.0, 0.0)), r"pattern.positional\[1\]: .* is pinned twice \(also pattern.positional\[0\]\)"),
    (((0, 1, 7), (0.0, 0.0, 1.0)), r"pattern.positional\[1\]: .* is pinned twice \(also pattern.positional\[0\]\)"),
])
def test_bad_points_are_refused_by_name(bar_model, entry, problem):
    with pytest.raises(PatternError, match=problem):
        bar_model.solver(Pattern(full=(0,), positional=(7, entry)))


def test_the_same_point_twice_is_refused_whatever_the_corner_order(bar_model):
    with pytest.raises(PatternError, match=r"pattern.positional\[1\]: .* is pinned twice \(also pattern.positional\[0\]\)"):
        bar_model.solver(Pattern(full=(0,), positional=(((3, 17, 40), (0.25, 0.25, 0.5)),
                                                         ((40, 3, 17), (0.5, 0.25, 0.25)))))


def test_a_bad_handle_leaves_the_pipeline_as_it_was():
    rig = load_rig(BUILTIN_RIG)
    corners, bary = tail_point(rig)
    with Pipeline(rig, render=False) as pipeline:
        pipeline.set_handles([(corners, bary)])
        pattern, solver, targets = pipeline.pattern, pipeline.solver, pipeline.handle_targets
        with pytest.raises(PatternError, match=r"barycentric weights sum to 0.75"):
            pipeline.set_handles([(corners, bary), (corners, (0.25, 0.25, 0.25))])
        with pytest.raises(PatternError, match=r"handles: 'tail' is neither a vertex index nor a surface point"):
            pipeline.set_handles([(corners, bary), "tail"])
        assert pipeline.pattern is pattern and pipeline.solver is solver and pipeline.handle_targets is targets


def test_handles_keep_the_rigs_contacts(tmp_path):
    # A rig with a contact (the tail tip's height), no dropout and no dynamics: adding a point handle keeps
    # the contact in the pattern and both hold.
    text = BUILTIN_RIG.read_text().replace('mesh = "critter.npz"', f'mesh = "{BUILTIN_RIG.parent / "critter.npz"}"')
    text = text[: text.index("[[pin]]")]
    tip = 12279
    path = tmp_path / "critter.toml"
    path.write_text(text + f'\n[[contact]]\nvertex = {tip}\naxes = "y"\nvalue = 0.02\n')
    rig = load_rig(path)
    ear = rig.skeleton.names.index("ear_L")
    vertex = int(np.argmax(rig.W[:, ear] * rig.V[:, 1]))
    F = np.asarray(rig.F, np.int64)
    corners = tuple(int(v) for v in F[np.flatnonzero((F == vertex).any(axis=1))[0]])
    bary = (0.3, 0.3, 0.4)
    diag = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    reads = performance(rig, 40)
    with Pipeline(rig, render=False) as pipeline:
        assert pipeline.live.dynamics is None and not pipeline.dropout.active
        pipeline.set_handles([(corners, bary)])
        assert pipeline.pattern.contacts == ((tip, "y"),)
        target = pipeline.handle_targets[0] + np.float32(0.1 * diag)
        pipeline.handle_targets[0] = target
        for reading in reads:
            pipeline.solve(reading)
        deformed = pipeline.deformed()
        assert np.linalg.norm(np.array(bary) @ deformed[list(corners)] - target) < 1e-4 * diag
        assert abs(deformed[tip, 1] - 0.02) < 1e-4 * diag
