"""Bounded biharmonic weights: computed with libigl when a rig has none, cached, validated;
clear reports for open meshes and skeletons outside the mesh."""

import numpy as np
import pytest

from puppet.rig import bbw, check_weights, load_rig
from puppet.rig.bbw import WeightInputError, bbw_weights, interpolate_in_tets
from puppet.rig.tgf_dmat import read_tgf


@pytest.fixture
def no_weights_rig(tube_rig_dir, monkeypatch):
    monkeypatch.setenv("PUPPET_CACHE", str(tube_rig_dir / "cache"))
    text = (tube_rig_dir / "tube.toml").read_text().replace('weights = "tube.dmat"\n', "")
    (tube_rig_dir / "auto.toml").write_text(text)
    return tube_rig_dir / "auto.toml"


def test_bbw_weights_are_valid_local_and_cached(no_weights_rig):
    rig = load_rig(no_weights_rig)
    report = rig.check_weights()
    assert report.ok, report.summary()
    assert rig.W.min() >= 0
    # each bone dominates the vertices beside it (bones along y: [0.1,1], [1,2], [2,2.9]).
    y = rig.V[:, 1]
    assert rig.W[y < 0.5].argmax(axis=1).tolist() == [0] * int((y < 0.5).sum())
    assert rig.W[(y > 1.3) & (y < 1.7)].argmax(axis=1).tolist() == [1] * int(((y > 1.3) & (y < 1.7)).sum())
    assert rig.W[y > 2.5].argmax(axis=1).tolist() == [2] * int((y > 2.5).sum())
    cached = list((no_weights_rig.parent / "cache").glob("bbw-*.npy"))
    assert len(cached) == 1
    np.testing.assert_array_equal(np.load(cached[0]), rig.W)
    # a cached result is used as is: overwrite it and see it come back.
    marker = np.full_like(rig.W, 1.0 / rig.W.shape[1])
    np.save(cached[0], marker)
    np.testing.assert_array_equal(load_rig(no_weights_rig).W, marker)


def test_edited_weights_code_misses_the_cache(no_weights_rig, monkeypatch):
    # The key covers the code that computes the weights: an edited bbw (or normalization, or
    # libigl) never serves the old code's weights.
    cache = no_weights_rig.parent / "cache"
    first = load_rig(no_weights_rig).W
    assert len(list(cache.glob("bbw-*.npy"))) == 1
    assert bbw.code_digest(bbw.__file__, bbw.weight_check.__file__) in bbw.code_version()
    monkeypatch.setattr(bbw, "code_version", lambda: "edited")
    real_tet, computed = bbw.bbw_tet, []
    monkeypatch.setattr(bbw, "bbw_tet", lambda *args, **kw: computed.append(1) or real_tet(*args, **kw))
    np.testing.assert_allclose(load_rig(no_weights_rig).W, first)
    assert computed == [1] and len(list(cache.glob("bbw-*.npy"))) == 2


def test_open_mesh_is_reported(tube_rig_dir):
    from puppet.rig.mesh_io import read_obj

    V, F = read_obj(tube_rig_dir / "tube.obj")
    skeleton, _ = read_tgf(tube_rig_dir / "tube.tgf")
    with pytest.raises(WeightInputError, match=r"not watertight: \d+ boundary edges") as err:
        bbw_weights(V, F[2:], skeleton, use_cache=False, path=tube_rig_dir / "tube.obj")
    assert "tube.obj" in str(err.value)


def test_skeleton_outside_the_mesh_is_reported(tube_rig_dir):
    from puppet.rig.mesh_io import read_obj

    V, F = read_obj(tube_rig_dir / "tube.obj")
    (tube_rig_dir / "far.tgf").write_text("1 0 0.1 0\n2 0 1 0\n3 5 1 0\n#\n1 2\n2 3\n")
    skeleton, _ = read_tgf(tube_rig_dir / "far.tgf")
    with pytest.raises(WeightInputError, match=r"skeleton lies outside the mesh at bones \['bone2'\]"):
        bbw_weights(V, F, skeleton, use_cache=False)


def test_check_weights_reports_each_problem():
    names = ("a", "b")
    assert check_weights(np.array([[0.5, 0.5], [1, 0]]), 2, names).ok
    negative = check_weights(np.array([[1.2, -0.2], [1, 0]]), 2, names)
    assert not negative.ok and "negative weight -0.2 at vertex 0, bone 'b'" in negative.problems[0]
    unity = check_weights(np.array([[0.5, 0.4], [1, 0]]), 2, names)
    assert unity.problems == ("weights of vertex 0 sum to 0.9, not 1",)
    shape = check_weights(np.ones((3, 2)) / 2, 2, names)
    assert shape.problems == ("shape (3, 2), expected (2, 2)",)
    nan = check_weights(np.array([[np.nan, 1], [1, 0]]), 2, names)
    assert not nan.ok and "non-finite" in nan.problems[0]


def test_interpolate_in_tets_is_exact_for_linear_fields():
    rng = np.random.default_rng(2)
    TV = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    TT = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    field = np.column_stack([TV @ [1.0, 2, 3] + 1, TV @ [-1.0, 0, 0.5]])
    inside = rng.dirichlet(np.ones(4), 30) @ TV[TT[0]]
    np.testing.assert_allclose(interpolate_in_tets(TV, TT, field, inside),
                               np.column_stack([inside @ [1.0, 2, 3] + 1, inside @ [-1.0, 0, 0.5]]), atol=1e-12)
