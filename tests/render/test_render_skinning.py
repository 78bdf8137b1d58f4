"""The vertex shader's positions equal M @ T computed on the CPU, for any weights."""

import numpy as np
import pytest

from puppet.render import Renderer, RenderInputError, lbs_matrix, pack_weights
from puppet.render.skin_weights import MAX_SLOTS, unpack_weights


def random_affine_T(rng, m: int) -> np.ndarray:
    """T (4m, 3) float32: random rotations-and-stretches plus translations."""
    blocks = []
    for _ in range(m):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        linear = q @ np.diag(rng.uniform(0.7, 1.4, 3))
        blocks.append(np.vstack([linear.T, rng.normal(scale=0.5, size=(1, 3))]))
    return np.concatenate(blocks).astype(np.float32)


@pytest.mark.parametrize("layout", ["dense", "pairs"])
def test_shader_positions_equal_M_T_for_two_bones(gl_context, bar, helpers, layout):
    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(np.pi / 2), [1, 0, 0])])
    with Renderer(V, F, W, width=64, height=48, weight_layout=layout, context=gl_context) as renderer:
        assert renderer.weight_layout == layout
        positions = renderer.skinned_positions(T)
    expected = lbs_matrix(V, W) @ T
    np.testing.assert_allclose(positions, expected, atol=1e-4)
    # The tip of the bar (x = 2, bone 1 only) went up to (1, 1, 0).
    tip = np.argmin(np.linalg.norm(V - [2.0, 0.0, 0.0], axis=1))
    np.testing.assert_allclose(positions[tip], [1.0, 1.0, 0.0], atol=1e-5)


@pytest.mark.parametrize("m, layout", [(60, "auto"), (40, "dense"), (40, "pairs")])
def test_shader_positions_equal_M_T_for_many_handles_and_mixed_sparsity(gl_context, helpers, m, layout):
    """Many handles (bones and extra weights): dense rows (more nonzeros than attribute slots:
    they spill into the texture), sparse rows, one-handle rows, negative weights."""
    rng = np.random.default_rng(m)
    V, F = helpers.tube(segments=30, sides=12)
    W = rng.uniform(-0.1, 1.0, size=(len(V), m))
    W[rng.random(W.shape) < 0.6] = 0.0  # sparse rows
    W[::5] = rng.uniform(0.0, 1.0, size=(len(W[::5]), m))  # fully dense rows
    W[1::7] = 0.0
    W[1::7, 13] = 1.0  # rows with one handle
    T = random_affine_T(rng, m)
    with Renderer(V, F, W, width=64, height=48, weight_layout=layout, context=gl_context) as renderer:
        assert renderer.weight_layout == ("pairs" if layout == "auto" else layout)
        assert renderer.max_weights_per_vertex == m
        assert renderer.dropped_weight_abs_max == 0.0
        positions = renderer.skinned_positions(T).copy()
        # T is uploaded per call: a second pose gives the second M @ T, not the first.
        T2 = random_affine_T(rng, m)
        positions2 = renderer.skinned_positions(T2)
        M = lbs_matrix(V, W).astype(np.float64)
        np.testing.assert_allclose(positions, M @ T, atol=1e-4)
        np.testing.assert_allclose(positions2, M @ T2, atol=1e-4)


def test_cpu_skinning_mode_draws_the_same_silhouette(gl_context, bar, helpers):
    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(1.0), [1, 0, 0])])
    masks = []
    for mode in ("gpu", "cpu"):
        with Renderer(V, F, W, width=160, height=120, skinning=mode, ground=False, samples=0,
                      background=(0, 0, 0), context=gl_context) as renderer:
            masks.append(renderer.draw(T).max(axis=2) > 8)
    assert masks[0].sum() > 500
    assert np.mean(masks[0] != masks[1]) < 0.002


def test_pack_weights_keeps_every_nonzero_and_reports_what_a_tolerance_drops():
    W = np.array([[0.5, 0.0, 0.5], [0.0, 0.0, 1.0], [1e-7, 0.3, 0.7]])
    exact = pack_weights(W)
    assert (exact.slots, exact.spilled, exact.count, exact.max_per_vertex) == (8, 0, 6, 3)
    assert exact.dropped_abs_max == 0.0
    np.testing.assert_array_equal(unpack_weights(exact, 3), W.astype(np.float32))
    # Largest weight first: vertex 2's slots are handles 2, 1, 0.
    assert exact.slot_handles[2, 0] == 2 | (1 << 16)
    assert exact.slot_handles[2, 1] & 0xFFFF == 0
    loose = pack_weights(W, tolerance=1e-6)
    assert loose.count == 5
    assert loose.dropped_abs_max == pytest.approx(1e-7)
    np.testing.assert_array_equal(unpack_weights(loose, 3)[2], np.float32([0.0, 0.3, 0.7]))


def test_pack_weights_spills_rows_with_more_than_the_attribute_slots():
    rng = np.random.default_rng(3)
    W = rng.random((30, 45))
    W[10:] *= rng.random((20, 45)) < 0.3  # sparse rows fit in the slots, dense rows spill
    packed = pack_weights(W)
    assert packed.slots == MAX_SLOTS
    counts = np.count_nonzero(W, axis=1)
    assert packed.spans[:, 1].tolist() == np.maximum(counts - MAX_SLOTS, 0).tolist()
    assert packed.spilled == int(np.maximum(counts - MAX_SLOTS, 0).sum())
    np.testing.assert_allclose(unpack_weights(packed, 45), W, rtol=1e-6)


def test_skinned_normals_follow_a_rigid_rotation(gl_context, bar, helpers):
    V, F, W = bar
    R = helpers.rotation_z(0.8)
    T = helpers.handle_T([helpers.rotation_about(R, [0.3, 0.1, 0])] * 2)
    with Renderer(V, F, W, width=32, height=32, context=gl_context) as renderer:
        rest = renderer.skinned_normals(helpers.handle_T([helpers.IDENTITY] * 2)).copy()
        posed = renderer.skinned_normals(T)
        side = np.abs(V[:, 0] - 1.0) < 0.5  # tube wall: rest normals point away from the x axis
        expected_side = V[side] * [0, 1, 1] / np.linalg.norm(V[side] * [0, 1, 1], axis=1, keepdims=True)
        unit = rest / np.linalg.norm(rest, axis=1, keepdims=True)
        np.testing.assert_allclose(unit[side], expected_side, atol=2e-2)
        np.testing.assert_allclose(posed / np.linalg.norm(posed, axis=1, keepdims=True), unit @ R.T, atol=1e-5)


def test_bad_T_and_bad_weights_name_the_field(gl_context, bar):
    V, F, W = bar
    with Renderer(V, F, W, width=32, height=32, context=gl_context) as renderer:
        with pytest.raises(RenderInputError, match=r"T: expected shape \(8, 3\)"):
            renderer.draw(np.zeros((12, 3), np.float32))
    with pytest.raises(RenderInputError, match="W: expected"):
        Renderer(V, F, W[:-1], context=gl_context)
    bad = W.copy()
    bad[5, 1] = np.nan
    with pytest.raises(RenderInputError, match="W: non-finite weight at vertex 5, handle 1"):
        Renderer(V, F, bad, context=gl_context)
    with pytest.raises(RenderInputError, match="F: vertex index out of range"):
        Renderer(V, F + len(V), W, context=gl_context)
    with pytest.raises(RenderInputError, match="weight_layout: dense takes at most 52 handles, W has 60"):
        Renderer(V, F, np.ones((len(V), 60)), weight_layout="dense", context=gl_context)


def test_sparse_skinning_gives_the_dense_vertices_and_image(gl_context, posed_critter):
    """Weights above 1e-6 only, as (weight, handle) pairs, against every weight of every handle."""
    rig, W, T, bones = posed_critter
    diagonal = float(np.linalg.norm(rig.V.max(axis=0) - rig.V.min(axis=0)))
    results = {}
    for layout, tolerance in (("dense", 0.0), ("pairs", 1e-6)):
        with Renderer(rig.V, rig.F, W, width=320, height=240, samples=0, fxaa=True, weight_layout=layout,
                      weight_tolerance=tolerance, context=gl_context) as renderer:
            assert renderer.weight_layout == layout
            if layout == "pairs":
                assert 0.0 < renderer.dropped_weight_abs_max <= 1e-6
                assert renderer.max_weights_per_vertex < W.shape[1]
            results[layout] = (renderer.skinned_positions(T).copy(), renderer.draw(T, bones=bones).copy())
    dense_positions, dense_image = results["dense"]
    sparse_positions, sparse_image = results["pairs"]
    np.testing.assert_allclose(dense_positions, lbs_matrix(rig.V, W).astype(np.float64) @ T, atol=1e-5 * diagonal)
    assert np.abs(sparse_positions - dense_positions).max() <= 1e-5 * diagonal
    difference = np.abs(sparse_image.astype(int) - dense_image.astype(int)).max(axis=2)
    assert difference.max() <= 16  # a pixel on a silhouette may round differently, nothing more
    assert np.mean(difference > 2) < 1e-3
