"""FAST precompute: extra weights, weight-space clusters, the cache."""

import numpy as np

from puppet.fast import FastModel
from puppet.fast.weights import bspline_bump


def test_bspline_bump_shape():
    x = np.linspace(0, 1.5, 301)
    b = bspline_bump(x)
    assert b[0] == 1.0 and (b[x >= 1.0] == 0.0).all()
    assert np.all(np.diff(b) <= 1e-12)  # monotone falloff
    np.testing.assert_allclose(bspline_bump(np.array([0.5])), 0.25)  # both pieces agree at 1/2


def test_extra_weights_partition_of_unity(bar):
    V, F, W = bar
    model = FastModel(V, F, W, clusters=10, extra_weights=3, cache_dir=False)
    assert model.m == 6 and model.m_bones == 3
    assert model.weights.shape == (len(V), 6) and model.weights.dtype == np.float32
    assert (model.weights >= 0).all()
    np.testing.assert_allclose(model.weights.sum(1), 1.0, atol=1e-6)
    extra = model.weights[:, 3:]
    # Each bump peaks somewhere and vanishes somewhere (compact support in weight space).
    assert (extra.max(0) > 0.2).all() and (extra.min(0) == 0).all()
    # The rest pose is every handle at the identity.
    np.testing.assert_allclose(model.deform(model.rest_T()), V, atol=1e-5)


def test_clusters_are_weight_space_kmeans(bar):
    V, F, W = bar
    model = FastModel(V, F, W, clusters=12, cache_dir=False)
    assert model.r == 12
    counts = np.bincount(model.labels)
    assert (counts > 0).all()
    # Lloyd optimality: each vertex is closest to its own cluster's centroid.
    Wd = model.weights.astype(np.float64)
    centres = np.stack([Wd[model.labels == g].mean(0) for g in range(model.r)])
    d = ((Wd[:, None, :] - centres[None]) ** 2).sum(-1)
    own = d[np.arange(len(V)), model.labels]
    assert np.mean(own <= d.min(1) + 1e-9) > 0.97
    # Clusters follow the weights: the rigid regions near either end share no cluster.
    assert model.labels[np.argmin(V[:, 0])] != model.labels[np.argmax(V[:, 0])]


def test_cache_round_trip(bar, tmp_path):
    V, F, W = bar
    a = FastModel(V, F, W, clusters=9, extra_weights=1, cache_dir=tmp_path)
    assert not a.cache_hit and len(list(tmp_path.glob("*.npz"))) == 1
    b = FastModel(V, F, W, clusters=9, extra_weights=1, cache_dir=tmp_path)
    assert b.cache_hit
    np.testing.assert_array_equal(a.weights, b.weights)
    np.testing.assert_array_equal(a.Q, b.Q)
    np.testing.assert_array_equal(a.K, b.K)
    # Any input change is a different key.
    c = FastModel(V, F, W, clusters=9, extra_weights=1, energy="spokes", cache_dir=tmp_path)
    assert not c.cache_hit and len(list(tmp_path.glob("*.npz"))) == 2
    # A corrupt entry is recomputed, not trusted.
    for p in tmp_path.glob("*.npz"):
        p.write_bytes(b"garbage")
    d = FastModel(V, F, W, clusters=9, extra_weights=1, cache_dir=tmp_path)
    assert not d.cache_hit
    np.testing.assert_array_equal(a.Q, d.Q)
