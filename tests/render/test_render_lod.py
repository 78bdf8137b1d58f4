"""The simplified copy a live loop draws on a software rasterizer: same vertices, same look,
picking on every triangle, cached."""

import numpy as np
import pytest

from puppet.render import Renderer, lod
from puppet.render.passes.picking import Picker


def _face_normals(V, F):
    return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])


def test_simplified_critter_keeps_its_vertices_orientation_and_closed_surface(posed_critter, monkeypatch, tmp_path):
    monkeypatch.setenv("PUPPET_CACHE", str(tmp_path))
    rig = posed_critter[0]
    V, F = rig.V, rig.F
    G = lod.simplified_triangles(V, F, 20_000)
    assert G.dtype == np.int32 and G.shape[1] == 3
    assert 19_000 <= len(G) <= 20_000
    assert G.min() >= 0 and G.max() < len(V)
    assert lod._closed_manifold(G)
    # Outward like the mesh: each triangle faces the way its corners' rest normals do.
    normals = np.zeros_like(V)
    for corner in range(3):
        np.add.at(normals, F[:, corner], _face_normals(V, F))
    facing = np.einsum("ij,ij->i", _face_normals(V, G), normals[G].sum(axis=1))
    assert (facing > 0).mean() > 0.99
    # Cached: a second call reads the entry instead of simplifying again.
    monkeypatch.setattr(lod, "_simplify", lambda *args: pytest.fail("simplified again"))
    np.testing.assert_array_equal(lod.simplified_triangles(V, F, 20_000), G)
    # A damaged entry is recomputed, not trusted.
    for entry in (tmp_path / "render").glob("lod-*.npy"):
        entry.write_bytes(b"\x93NUMPY damaged")
    monkeypatch.undo()
    monkeypatch.setenv("PUPPET_CACHE", str(tmp_path))
    np.testing.assert_array_equal(lod.simplified_triangles(V, F, 20_000), G)


def test_open_or_small_meshes_are_drawn_whole(bar):
    V, F, _ = bar  # a capped tube: closed
    assert len(lod.simplified_triangles(V, F, len(F) // 2, cache=False)) <= len(F) // 2
    np.testing.assert_array_equal(lod.simplified_triangles(V, F, len(F), cache=False), F)
    open_tube = F[: -2 * 16]  # without its caps (16 sides): an open surface keeps every triangle
    np.testing.assert_array_equal(lod.simplified_triangles(V, open_tube, len(F) // 4, cache=False), open_tube)


def test_the_simplified_critter_looks_the_same_and_picks_every_triangle(gl_context, posed_critter):
    rig, W, T, bones = posed_critter
    images, picks = {}, {}
    pixels = [(x, y) for x in range(200, 440, 24) for y in range(60, 440, 24)]
    for budget in (None, 640 * 480 // 12):
        with Renderer(rig.V, rig.F, W, samples=0, fxaa=True, context=gl_context, triangle_budget=budget) as r:
            images[budget] = r.draw(T, bones=bones).copy()
            assert r.drawn_triangles == (len(rig.F) if budget is None else budget)
            with Picker(r) as picker:
                picks[budget] = [picker.pick(T, r.camera, x, y) for x, y in pixels]
    difference = np.abs(images[None].astype(int) - images[25_600].astype(int)).max(axis=2)
    assert (difference > 16).mean() < 0.005
    assert (difference > 0).any()
    assert sum(p is not None for p in picks[None]) >= 20  # on the character
    assert picks[25_600] == picks[None]  # the same triangle of the full mesh, the same point


def test_skinned_vertices_come_back_in_the_callers_order(gl_context, posed_critter):
    """The simplified draw skins only its own vertices each frame (they come first inside the
    renderer); skinned_positions() and skinned_normals() still give every vertex, in V's order."""
    rig, W, T, bones = posed_critter
    results = {}
    for budget in (None, 25_600):
        with Renderer(rig.V, rig.F, W, samples=0, fxaa=True, context=gl_context, triangle_budget=budget) as r:
            r.draw(T, bones=bones)
            results[budget] = (r.skinned_positions(T).copy(), r.skinned_normals(T).copy(), r._skin_count)
    np.testing.assert_array_equal(results[25_600][0], results[None][0])
    np.testing.assert_array_equal(results[25_600][1], results[None][1])
    assert results[None][2] == len(rig.V) and results[25_600][2] < 0.6 * len(rig.V)


def test_a_mesh_libigl_cannot_simplify_is_drawn_whole(bar, monkeypatch):
    import igl

    def refuse(*args, **kwargs):
        raise RuntimeError("decimate refused")

    monkeypatch.setattr(igl, "decimate", refuse)
    V, F, _ = bar
    np.testing.assert_array_equal(lod.simplified_triangles(V, F, len(F) // 2, cache=False), F)
