"""Bad input to the FAST precompute and solve: a clear typed error or a documented repair,
never NaN output."""

import numpy as np
import pytest

from puppet.fast import FastModel, MeshError, Pattern, PatternError, WeightsError


def small_bar(helpers):
    return helpers.make_bar(nl=20, nr=10)


@pytest.fixture(scope="module")
def solved(bar_model):
    pattern = Pattern(full=(0,), relative=((1, 0, (4.0 / 3, 0, 0)),), positional=(int(np.argmax(bar_model.V[:, 0])),))
    solver = bar_model.solver(pattern)
    values = pattern.values()
    values.full[0] = bar_model.rest_T()[:4]
    values.positional[0] = bar_model.V[pattern.positional[0]]
    return bar_model, solver, values


@pytest.mark.parametrize("field", ["full", "relative", "positional"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_values_are_refused_and_T_untouched(solved, field, bad):
    model, solver, values = solved
    broken = type(values)(values.full.copy(), values.relative.copy(), values.positional.copy())
    getattr(broken, field).flat[1] = bad
    T = model.rest_T()
    before = T.copy()
    with pytest.raises(ValueError, match=f"values.{field} contains NaN or inf"):
        solver.solve(broken, T)
    np.testing.assert_array_equal(T, before)


def test_non_finite_warm_start_is_refused(solved):
    model, solver, values = solved
    T = model.rest_T()
    T[5, 1] = np.nan
    with pytest.raises(ValueError, match="T contains NaN"):
        solver.solve(values, T)


def test_wrong_dtype_or_layout_is_a_type_error(solved):
    model, solver, values = solved
    with pytest.raises(TypeError):
        solver.solve(values, model.rest_T().astype(np.float64))
    with pytest.raises(TypeError):
        solver.solve(values, np.asfortranarray(np.zeros((4 * model.m, 3), np.float32))[:, :])
    with pytest.raises(TypeError):
        solver.solve(values, np.zeros((4 * model.m, 4), np.float32))
    bad = type(values)(values.full.astype(np.float64), values.relative, values.positional)
    with pytest.raises(TypeError):
        solver.solve(bad, model.rest_T())


def test_wrong_counts_are_value_errors(solved):
    model, solver, values = solved
    with pytest.raises(ValueError, match="T has"):
        solver.solve(values, np.zeros((4 * model.m - 4, 3), np.float32))
    bad = type(values)(np.zeros((2, 4, 3), np.float32), values.relative, values.positional)
    with pytest.raises(ValueError, match="values.full has 2 rows, the pattern needs 1"):
        solver.solve(bad, model.rest_T())


def test_negative_or_non_summing_weights(helpers):
    V, F, W = small_bar(helpers)
    Wn = W.copy()
    Wn[3, 0] = -0.2
    with pytest.raises(WeightsError, match="negative weights"):
        FastModel(V, F, Wn, clusters=4, cache_dir=False)
    Ws = W * 1.2
    with pytest.raises(WeightsError, match="do not sum to one"):
        FastModel(V, F, Ws, clusters=4, cache_dir=False)
    Wz = W.copy()
    Wz[5] = 0.0
    with pytest.raises(WeightsError, match=r"rows \[5\] sum to zero"):
        FastModel(V, F, Wz, clusters=4, cache_dir=False, normalize_weights=True)
    with pytest.raises(WeightsError, match="shape"):
        FastModel(V, F, W[:-1], clusters=4, cache_dir=False)
    Wnan = W.copy()
    Wnan[2, 1] = np.nan
    with pytest.raises(WeightsError, match=r"rows \[2\] contain NaN"):
        FastModel(V, F, Wnan, clusters=4, cache_dir=False)
    # Documented repair: clip and renormalise.
    model = FastModel(V, F, np.where(Wn < 0, -0.2, Ws), clusters=4, cache_dir=False, normalize_weights=True)
    assert (model.weights >= 0).all()
    np.testing.assert_allclose(model.weights.sum(1), 1.0, atol=1e-6)


def test_bad_mesh(helpers):
    V, F, W = small_bar(helpers)
    with pytest.raises(MeshError, match="V: shape"):
        FastModel(V[:, :2], F, W, cache_dir=False)
    Vn = V.copy()
    Vn[4, 2] = np.inf
    with pytest.raises(MeshError, match=r"V: rows \[4\]"):
        FastModel(Vn, F, W, cache_dir=False)
    with pytest.raises(MeshError, match="F: indices"):
        FastModel(V, F + len(V), W, cache_dir=False)
    with pytest.raises(MeshError, match="F: dtype"):
        FastModel(V, F.astype(np.float64), W, cache_dir=False)
    with pytest.raises(MeshError, match="spokes_and_rims"):
        FastModel(V, F, W, tets=np.array([[0, 1, 2, 30]]), cache_dir=False)


def test_zero_area_triangles_are_dropped_not_nan(helpers):
    V, F, W = small_bar(helpers)
    F2 = np.vstack([F, [[0, 0, 1], [3, 4, 3]]])  # repeated corners: zero area
    V2 = V.copy()
    # A collinear (flat) triangle too: the middle vertex on its neighbours' segment.
    F2 = np.vstack([F2, [[0, 10, 20]]])
    V2[10] = 0.5 * (V2[0] + V2[20])
    model = FastModel(V2, F2, W, clusters=4, cache_dir=False)
    assert model.dropped_elements == 3
    assert np.isfinite(model.Q).all() and np.isfinite(model.K).all()
    pattern = Pattern(full=(0,))
    values = pattern.values()
    values.full[0] = model.rest_T()[:4]
    values.full[0, 3] = (1.0, 0.5, 0.0)
    T = model.rest_T()
    stats = model.solver(pattern).solve(values, T, iterations=5)
    assert np.isfinite(T).all() and np.isfinite(stats.energy)


def test_all_degenerate_mesh_is_refused(helpers):
    V, F, W = small_bar(helpers)
    with pytest.raises(MeshError, match="every element is degenerate"):
        FastModel(V, np.array([[0, 0, 1], [2, 2, 2]]), W, cache_dir=False)


def test_empty_clusters_are_compacted(helpers):
    V, F, W = small_bar(helpers)
    labels = (np.arange(len(V)) % 3) * 5  # labels 0, 5, 10: clusters 1-4 and 6-9 empty
    model = FastModel(V, F, W, clusters=labels, cache_dir=False)
    assert model.r == 3
    assert sorted(np.unique(model.labels)) == [0, 1, 2]
    # More clusters asked than distinct weight rows: empty ones are dropped, never NaN.
    Wr = np.zeros_like(W)
    Wr[np.arange(len(V)), np.minimum((V[:, 0] * 3 / 4).astype(int), 2)] = 1.0
    model = FastModel(V, F, Wr, clusters=50, cache_dir=False)
    assert model.r == 3
    pattern = Pattern(full=(0,))
    values = pattern.values()
    values.full[0] = model.rest_T()[:4]
    T = model.rest_T()
    model.solver(pattern).solve(values, T, iterations=3)
    assert np.isfinite(T).all()


def test_bad_clusters_argument(helpers):
    V, F, W = small_bar(helpers)
    with pytest.raises(ValueError, match="clusters"):
        FastModel(V, F, W, clusters=0, cache_dir=False)
    with pytest.raises(ValueError, match="clusters: labels"):
        FastModel(V, F, W, clusters=np.zeros(len(V) - 1, int), cache_dir=False)


def test_under_constrained_patterns_are_refused(bar_model):
    model = bar_model
    with pytest.raises(PatternError, match="global translation is free"):
        model.solver(Pattern())
    with pytest.raises(PatternError, match="global translation is free"):
        model.solver(Pattern(relative=((1, 0, (1.0, 0, 0)),)))


def test_malformed_patterns_are_refused(bar_model):
    model = bar_model
    with pytest.raises(PatternError, match="handle 9 is not in"):
        model.solver(Pattern(full=(9,)))
    with pytest.raises(PatternError, match="repeated"):
        model.solver(Pattern(full=(0, 0)))
    with pytest.raises(PatternError, match="also a full handle"):
        model.solver(Pattern(full=(0, 1), relative=((1, 0, (1.0, 0, 0)),)))
    with pytest.raises(PatternError, match="its own parent"):
        model.solver(Pattern(full=(0,), relative=((1, 1, (1.0, 0, 0)),)))
    with pytest.raises(PatternError, match="pivot"):
        model.solver(Pattern(full=(0,), relative=((1, 0, (np.nan, 0, 0)),)))
    with pytest.raises(PatternError, match="vertex"):
        model.solver(Pattern(full=(0,), positional=(10**7,)))
    # A vertex bound only to a full handle: its pin is redundant.
    v = int(np.argmax(model.weights[:, 0]))
    rigid = Pattern(full=tuple(range(model.m)), positional=(v,))
    with pytest.raises(PatternError, match="redundant"):
        model.solver(rigid)
    with pytest.raises(PatternError, match="over-determine"):
        model.solver(Pattern(full=(0,), relative=((1, 2, (1.0, 0, 0)), (2, 1, (2.0, 0, 0)))))


def test_a_solve_follows_its_arrays_when_they_change_or_are_replaced(bar_model):
    """The native call keeps the last call's arrays (checked once): the same objects with new
    contents, new objects, and a good call after a refused one all solve what they are handed."""
    pattern = Pattern(full=(0,), positional=(int(np.argmax(bar_model.V[:, 0])),))
    solver, fresh = bar_model.solver(pattern), bar_model.solver(pattern)
    values = pattern.values()
    values.full[0] = bar_model.rest_T()[:4]
    tip = bar_model.V[pattern.positional[0]]

    def reference(target, T0):  # a solver that has never seen these arrays
        v = pattern.values()
        v.full[:], v.positional[0] = values.full, target
        T = T0.copy()
        fresh.solve(v, T, iterations=5, accelerate=False)
        return T

    T = bar_model.rest_T()
    for k, target in enumerate((tip + [0, 0.3, 0], tip + [0, -0.2, 0.1])):  # same objects, new contents
        values.positional[0] = target
        want = reference(target, T)
        solver.solve(values, T, iterations=5, accelerate=False)
        np.testing.assert_array_equal(T, want, err_msg=f"frame {k}")
    moved = T.copy()
    values.positional = np.array([tip + [0.1, 0.4, 0]], np.float32)  # a new positional array
    T2 = bar_model.rest_T()  # and a new T: the old one is left alone
    want = reference(values.positional[0], T2)
    solver.solve(values, T2, iterations=5, accelerate=False)
    np.testing.assert_array_equal(T2, want)
    np.testing.assert_array_equal(T, moved)
    with pytest.raises(TypeError, match="solve: T must be a C-contiguous float32 array"):
        solver.solve(values, T2.astype(np.float64))
    with pytest.raises(ValueError, match="T has"):
        solver.solve(values, np.zeros((4 * bar_model.m + 4, 3), np.float32))
    want = reference(values.positional[0], T)
    solver.solve(values, T, iterations=5, accelerate=False)
    np.testing.assert_array_equal(T, want)
