"""The on-disk cache: one root (PUPPET_CACHE), never the user's home in tests, keys that cover
the code, and failures that are logged instead of silently dropped."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest
from puppet import cache
from puppet.fast import FastModel, model as fast_model
from puppet.rig import bbw


def _tube(nl=16, nr=10, bones=2):
    """A small closed tube along x with smooth weights: V (n, 3), F, W (n, bones)."""
    x = np.linspace(0.0, 2.0, nl)
    t = np.linspace(0.0, 2 * np.pi, nr, endpoint=False)
    X, A = np.meshgrid(x, t, indexing="ij")
    V = np.stack([X, 0.4 * np.cos(A), 0.4 * np.sin(A)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nl - 1), np.arange(nr), indexing="ij")
    a, b = (i * nr + j).ravel(), (i * nr + (j + 1) % nr).ravel()
    F = np.concatenate([np.stack([a, b, b + nr], 1), np.stack([a, b + nr, a + nr], 1)])
    W = np.exp(-(((V[:, :1] - np.array([[0.5, 1.5]])) / 0.5) ** 2))
    return V, F, W / W.sum(1, keepdims=True)


def test_tests_never_use_the_home_cache(private_cache):
    home = Path.home() / ".cache"
    assert os.environ["PUPPET_CACHE"] == str(private_cache)
    assert cache.cache_root() == private_cache
    assert not str(cache.cache_root()).startswith(str(home))
    assert fast_model.default_cache_dir() == private_cache / "fast"
    assert bbw.default_cache_dir() == private_cache
    V, F, W = _tube()
    FastModel(V, F, W, clusters=5)                       # the default cache folder
    assert list((private_cache / "fast").glob("*.npz"))


def test_one_variable_names_the_root(monkeypatch, tmp_path):
    monkeypatch.setenv("PUPPET_CACHE", str(tmp_path / "root"))
    monkeypatch.setenv("PUPPET_CACHE_DIR", str(tmp_path / "other"))   # the old name: ignored
    assert cache.cache_root() == tmp_path / "root"
    assert fast_model.default_cache_dir() == tmp_path / "root" / "fast"
    monkeypatch.delenv("PUPPET_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.cache_root() == tmp_path / "xdg" / "puppet"


def test_the_precompute_key_covers_the_code(monkeypatch, tmp_path):
    V, F, W = _tube()
    assert not FastModel(V, F, W, clusters=5, cache_dir=tmp_path).cache_hit
    assert FastModel(V, F, W, clusters=5, cache_dir=tmp_path).cache_hit
    # Edited code (puppet/fast or the native module): a new key, nothing stale reused.
    monkeypatch.setattr(fast_model, "code_version", lambda: "edited")
    assert not FastModel(V, F, W, clusters=5, cache_dir=tmp_path).cache_hit
    assert len(list(tmp_path.glob("*.npz"))) == 2


def test_code_digest_follows_every_source_file(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "a.py").write_text("x = 1\n")
    (package / "sub" / "b.py").write_text("y = 2\n")
    module = tmp_path / "native.so"
    module.write_bytes(b"\x7fELF one")
    first = cache.code_digest.__wrapped__(str(package), str(module))
    (package / "sub" / "b.py").write_text("y = 3\n")
    second = cache.code_digest.__wrapped__(str(package), str(module))
    module.write_bytes(b"\x7fELF two")
    third = cache.code_digest.__wrapped__(str(package), str(module))
    assert len({first, second, third}) == 3
    assert fast_model.code_version() == fast_model.code_version()   # stable within a run


def test_cache_failures_are_logged(tmp_path, caplog):
    V, F, W = _tube()
    a = FastModel(V, F, W, clusters=5, cache_dir=tmp_path)
    for entry in tmp_path.glob("*.npz"):
        entry.write_bytes(b"garbage")
    with caplog.at_level(logging.WARNING, logger="puppet.cache"):
        b = FastModel(V, F, W, clusters=5, cache_dir=tmp_path)
    assert not b.cache_hit
    np.testing.assert_array_equal(a.Q, b.Q)
    assert any("unreadable" in r.getMessage() and str(tmp_path) in r.getMessage() for r in caplog.records)

    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the cache folder should be")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="puppet.cache"):
        c = FastModel(V, F, W, clusters=5, cache_dir=blocked)
    np.testing.assert_array_equal(a.Q, c.Q)
    assert any("not written" in r.getMessage() and str(blocked) in r.getMessage() for r in caplog.records)


def test_an_entry_is_keyed_by_the_code_digest_and_every_input(tmp_path, caplog):
    data = np.arange(6, dtype=np.float64).reshape(2, 3)
    entry = cache.Entry.keyed(tmp_path, "part", ".npy", "code-1", data, 7)
    assert entry.path.parent == tmp_path and entry.path.name.startswith("part-")
    assert entry.load(np.load) is None                     # nothing stored yet
    entry.store(lambda tmp: np.save(tmp, data))
    np.testing.assert_array_equal(cache.Entry.keyed(tmp_path, "part", ".npy", "code-1", data, 7).load(np.load), data)
    # Another code digest, another input (value, dtype or shape): another entry, a miss.
    for other in [("code-2", data, 7), ("code-1", data, 8), ("code-1", data.astype(np.float32), 7),
                  ("code-1", data.reshape(3, 2), 7)]:
        assert cache.Entry.keyed(tmp_path, "part", ".npy", *other).load(np.load) is None
    # A stored value the reader refuses is a logged miss.
    def refuse(path):
        raise ValueError("not what this part stores")

    with caplog.at_level(logging.WARNING, logger="puppet.cache"):
        assert entry.load(refuse) is None
    assert any("unreadable" in r.getMessage() and str(entry.path) in r.getMessage() for r in caplog.records)


def test_the_lod_key_covers_the_code(monkeypatch, tmp_path):
    from puppet.render import lod

    monkeypatch.setenv("PUPPET_CACHE", str(tmp_path))
    V, F, _ = _tube()
    first = lod.simplified_triangles(V, F, len(F) // 2)
    assert len(list((tmp_path / "render").glob("lod-*.npy"))) == 1
    monkeypatch.setattr(lod, "_simplify", lambda *args: pytest.fail("simplified again"))
    np.testing.assert_array_equal(lod.simplified_triangles(V, F, len(F) // 2), first)  # a hit
    # Edited lod code: a new key, computed again (nothing stale reused).
    monkeypatch.setattr(lod, "code_digest", lambda *paths: "edited")
    with pytest.raises(pytest.fail.Exception, match="simplified again"):
        lod.simplified_triangles(V, F, len(F) // 2)
