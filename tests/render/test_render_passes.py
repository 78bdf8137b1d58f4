"""The renderer's passes own their GL objects: a renderer or a pass that fails half-way
releases what it made; the FXAA rectangle comes from a CPU bound of the skinned mesh that holds
every vertex, with no read-back."""

import moderngl
import numpy as np
import pytest

import puppet.render.renderer as renderer_module
from puppet.render import Renderer
from puppet.render.bounds import SkinnedBounds
from puppet.render.passes import antialias, base
from puppet.render.skin_weights import lbs_matrix


class Boom(Exception):
    pass


@pytest.fixture
def owned(monkeypatch):
    """Every GL object any pass records as its own, in the order made."""
    made = []
    own = base.GLPass.own

    def recording(self, obj):
        made.append(obj)
        return own(self, obj)

    monkeypatch.setattr(base.GLPass, "own", recording)
    return made


def released(obj) -> bool:
    return isinstance(obj.mglo, moderngl.mgl.InvalidObject)


def test_a_renderer_whose_last_pass_fails_releases_the_passes_it_built(gl_context, bar, owned, monkeypatch):
    V, F, W = bar

    def failing(*args, **kwargs):
        raise Boom("antialias pass")

    monkeypatch.setattr(renderer_module, "AntialiasPass", failing)
    with pytest.raises(Boom):
        Renderer(V, F, W, width=64, height=48, samples=0, fxaa=True, context=gl_context)
    kinds = {type(obj).__name__ for obj in owned}
    assert {"Buffer", "Program", "VertexArray", "Texture", "Framebuffer"} <= kinds  # mesh, ground, bones
    assert [obj for obj in owned if not released(obj)] == []


def test_a_pass_that_fails_half_way_releases_what_it_made(gl_context, bar, owned, monkeypatch):
    """The antialias pass made its framebuffers, then its second FXAA shader does not compile:
    its own objects and the earlier passes' are all released, the error reaches the caller."""
    V, F, W = bar
    monkeypatch.setattr(antialias.shaders, "FXAA_BLUR_FRAGMENT", "#version 330\nnot glsl;\n")
    with pytest.raises(moderngl.Error):
        Renderer(V, F, W, width=64, height=48, samples=0, fxaa=True, context=gl_context)
    framebuffers = [obj for obj in owned if isinstance(obj, moderngl.Framebuffer)]
    assert len(framebuffers) >= 2  # resolved and target were made before the failure
    assert [obj for obj in owned if not released(obj)] == []
    # The context is still usable: a renderer built next draws.
    monkeypatch.undo()
    with Renderer(V, F, W, width=64, height=48, samples=0, fxaa=True, context=gl_context) as r:
        assert r.draw(np.tile(np.vstack([np.eye(3), np.zeros(3)]), (2, 1)).astype(np.float32)).any()


def test_release_frees_every_pass_once(gl_context, bar, owned, helpers):
    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.IDENTITY])
    r = Renderer(V, F, W, width=64, height=48, samples=0, fxaa=True, context=gl_context)
    r.draw(T, bones=[[[0, 0, 0], [1, 0, 0]], [[1, 0, 0], [2, 0, 0]]])  # the bones' buffers, a backdrop
    assert len(owned) > 20
    assert not any(released(obj) for obj in owned)
    r.release()
    r.release()
    assert [obj for obj in owned if not released(obj)] == []


def test_the_skinned_bound_holds_every_vertex_for_any_weights_and_transforms():
    """Weights that are negative and do not sum to one, random affine transforms with big
    translations: the box holds M @ T, and it is not loose for a rigid motion."""
    rng = np.random.default_rng(3)
    V = rng.normal(size=(3000, 3))
    W = rng.random((3000, 5)) ** 4
    W[:, 0] -= 0.1
    bounds = SkinnedBounds(V, W, clusters=32)
    M = lbs_matrix(V, W)
    for _ in range(20):
        T = (rng.normal(size=(20, 3)) * [1, 1, 1] + 0).astype(np.float32)
        T[3::4] *= 10.0  # translations
        P = M @ T
        box = bounds.box(T)
        assert np.all(box[0] <= P.min(axis=0) + 1e-4)
        assert np.all(box[1] >= P.max(axis=0) - 1e-4)
    rigid = SkinnedBounds(V, np.full((3000, 2), 0.5), clusters=32)
    angle = 0.7
    R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    T = np.tile(np.vstack([R.T, [5.0, -2.0, 1.0]]), (2, 1)).astype(np.float32)
    P = V @ R.T + [5.0, -2.0, 1.0]
    box = rigid.box(T)
    extent = P.max(axis=0) - P.min(axis=0)
    assert np.all(box[0] <= P.min(axis=0) + 1e-4) and np.all(box[1] >= P.max(axis=0) - 1e-4)
    assert np.all((box[1] - box[0]) < 1.5 * extent)


@pytest.mark.parametrize("skinning", ["gpu", "cpu"])
def test_fxaa_rectangle_holds_the_posed_critter(gl_context, posed_critter, skinning):
    """The character's rectangle, bounded on the CPU, holds every skinned vertex's pixel, is a
    part of the frame, and FXAA over it equals FXAA over the whole frame (also when skinned on
    the CPU, where nothing is in the transform-feedback buffer)."""
    rig, W, T, bones = posed_critter
    images = {}
    for region in ("character", "frame"):
        with Renderer(rig.V, rig.F, W, width=320, height=240, samples=0, fxaa=True, fxaa_region=region,
                      skinning=skinning, context=gl_context) as r:
            images[region] = r.draw(T).copy()
            if region == "character":
                x, y, w, h = r.antialias.rect
                assert 0 < w * h < 0.6 * 320 * 240
                pixels = r.camera.to_pixels(lbs_matrix(rig.V, W) @ T, r.width, r.height)
                # Framebuffer rows are image rows: the projection is flipped (top row first).
                assert x <= pixels[:, 0].min() and pixels[:, 0].max() <= x + w
                assert y <= pixels[:, 1].min() and pixels[:, 1].max() <= y + h
    assert np.abs(images["character"].astype(int) - images["frame"].astype(int)).max() <= 2
