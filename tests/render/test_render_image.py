"""Rendered images: silhouettes move where the bones go, overlay colors, contact shadow, framing.

Images are compared through masks and tolerances, never byte for byte.
"""

import numpy as np
import pytest

import puppet.render.context as render_context
from puppet.render import EGL_PACKAGES, Camera, Renderer, RenderError, RenderInputError

BLACK = (0.0, 0.0, 0.0)


def pixel_of(renderer: Renderer, point) -> tuple[int, int]:
    """(row, column) of a world point in renderer's images (top row first): Camera.to_pixels,
    checked here against what the renderer draws."""
    x, y = renderer.camera.to_pixels(point, renderer.width, renderer.height)[0]
    return int(y), int(x)


def front_camera() -> Camera:
    return Camera(eye=[1.0, 0.5, 6.0], target=[1.0, 0.5, 0.0], fov_deg=35.0)


def test_bending_one_bone_moves_the_silhouette(gl_context, bar, helpers):
    V, F, W = bar
    rest = helpers.handle_T([helpers.IDENTITY, helpers.IDENTITY])
    bent = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(np.pi / 2), [1, 0, 0])])
    with Renderer(V, F, W, width=160, height=120, camera=front_camera(), ground=False, background=BLACK,
                  context=gl_context) as renderer:
        rest_mask = renderer.draw(rest).max(axis=2) > 20
        bent_mask = renderer.draw(bent).max(axis=2) > 20
        tip, raised, root = (pixel_of(renderer, p) for p in ([1.75, 0, 0], [1.0, 0.75, 0], [0.3, 0, 0]))
    assert raised[0] < root[0]  # up in the world is up in the image
    assert (rest_mask[tip], bent_mask[tip]) == (True, False)  # the tip left its rest place...
    assert (rest_mask[raised], bent_mask[raised]) == (False, True)  # ...and went up
    assert (rest_mask[root], bent_mask[root]) == (True, True)  # bone 0 did not move
    upper = slice(0, root[0] - 8)
    assert rest_mask[upper].sum() == 0
    assert bent_mask[upper].sum() > 300


def test_skeleton_overlay_colors_bones_by_state(gl_context, bar, helpers):
    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(np.pi / 2), [1, 0, 0])])
    bones = np.array([[[0.0, 0, 0], [1.0, 0, 0]], [[1.0, 0, 0], [2.0, 0, 0]]])
    with Renderer(V, F, W, width=160, height=120, camera=front_camera(), ground=False, context=gl_context) as renderer:
        plain = renderer.draw(T).astype(int)
        image = renderer.draw(T, bones=bones, bone_states=["sensed", "fault"]).astype(int)
        sensed_px = pixel_of(renderer, [0.5, 0, 0])
        faulted_px = pixel_of(renderer, [1.0, 0.5, 0])  # bone 1 moved with handle 1
        with pytest.raises(RenderInputError, match=r"bone_states\[1\]: unknown state 'broken'"):
            renderer.draw(T, bones=bones, bone_states=["sensed", "broken"])
        with pytest.raises(RenderInputError, match="bone_states: 1 states for 2 bones"):
            renderer.draw(T, bones=bones, bone_states=["free"])
    r, g, b = image[sensed_px]
    assert g > 150 and r < 80 and b < 100
    r, g, b = image[faulted_px]
    assert r > 150 and g < 80 and b < 80
    assert np.abs(plain[faulted_px] - image[faulted_px]).max() > 60


def test_contact_shadow_darkens_the_ground_under_the_character_and_follows_the_pose(gl_context, bar, helpers):
    V, F, W = bar  # the tube's lowest points are at y = -0.2: it lies on the ground
    rest = helpers.handle_T([helpers.IDENTITY, helpers.IDENTITY])
    bent = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(np.pi / 2), [1, 0, 0])])
    camera = Camera(eye=[1.0, 2.5, 3.5], target=[1.0, -0.2, 0.0], fov_deg=40.0)
    with Renderer(V, F, W, width=200, height=150, camera=camera, context=gl_context) as renderer:
        rest_img = renderer.draw(rest).astype(float).mean(axis=2)
        bent_img = renderer.draw(bent).astype(float).mean(axis=2)
        beside_root = pixel_of(renderer, [0.4, -0.2, 0.26])
        beside_tip = pixel_of(renderer, [1.75, -0.2, 0.26])
        open_ground = pixel_of(renderer, [1.0, -0.2, 1.3])
    assert rest_img[beside_root] < rest_img[open_ground] - 12
    assert rest_img[beside_tip] < rest_img[open_ground] - 12
    # The tip went up: the ground beside its rest place is lit again; the root stays shaded.
    tip_change = bent_img[beside_tip] - rest_img[beside_tip]
    assert tip_change > 8
    assert abs(bent_img[beside_root] - rest_img[beside_root]) < tip_change / 2


def test_automatic_framing_shows_the_whole_rest_pose(gl_context, bar, helpers):
    V, F, W = bar
    with Renderer(V, F, W, width=120, height=160, context=gl_context) as renderer:  # portrait
        cam = renderer.camera
        clip = (cam.projection_matrix(120 / 160, renderer._radius) @ cam.view_matrix() @ np.c_[V, np.ones(len(V))].T).T
        ndc = clip[:, :2] / clip[:, 3:]
        assert np.abs(ndc).max() <= 1.0
        assert np.abs(ndc).max() > 0.75  # and fills the frame
        image = renderer.draw(helpers.handle_T([helpers.IDENTITY, helpers.IDENTITY]))
    assert image.shape == (160, 120, 3) and image.dtype == np.uint8


def test_framing_along_a_given_view_shows_the_character_where_to_pixels_says(gl_context, bar, helpers):
    """Camera.framing(view=...) looks from exactly that direction, and the drawn silhouette lies
    in the box Camera.to_pixels gives for the vertices (a pixel of antialiasing either way)."""
    V, F, W = bar
    view = np.array([0.3, -0.2, 1.0])
    camera = Camera.framing(V, aspect=160 / 120, up=(0.0, 1.0, 0.0), view=view, margin=1.2)
    np.testing.assert_allclose(camera.basis()[2], view / np.linalg.norm(view), atol=1e-12)
    with Renderer(V, F, W, width=160, height=120, camera=camera, ground=False, background=BLACK,
                  context=gl_context) as renderer:
        mask = renderer.draw(helpers.handle_T([helpers.IDENTITY, helpers.IDENTITY])).max(axis=2) > 20
    rows, cols = np.nonzero(mask)
    pixels = camera.to_pixels(V, 160, 120)
    assert abs(cols.min() - pixels[:, 0].min()) <= 1.5 and abs(cols.max() + 1 - pixels[:, 0].max()) <= 1.5
    assert abs(rows.min() - pixels[:, 1].min()) <= 1.5 and abs(rows.max() + 1 - pixels[:, 1].max()) <= 1.5


def test_draw_reads_into_out_and_reuses_its_own_buffer(gl_context, bar, helpers):
    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.IDENTITY])
    with Renderer(V, F, W, width=64, height=48, samples=64, context=gl_context) as renderer:
        assert renderer.samples == gl_context.max_samples
        first = renderer.draw(T)
        assert renderer.draw(T) is first
        out = np.zeros((48, 64, 3), np.uint8)
        assert renderer.draw(T, out=out) is out
        assert np.abs(out.astype(int) - first.astype(int)).max() <= 2
        with pytest.raises(RenderInputError, match="out: expected C-contiguous uint8"):
            renderer.draw(T, out=np.zeros((64, 48, 3), np.uint8))


def test_missing_egl_library_names_the_packages_to_install(monkeypatch):
    monkeypatch.setattr(render_context.ctypes.util, "find_library", lambda name: None)
    with pytest.raises(RenderError, match="libEGL not found") as info:
        render_context.create_context()
    for package in EGL_PACKAGES:
        assert package in str(info.value)


def test_failing_egl_context_names_the_packages_to_install(monkeypatch):
    def no_display(**kwargs):
        raise Exception("eglGetDisplay failed")  # what glcontext raises

    monkeypatch.setattr(render_context.moderngl, "create_standalone_context", no_display)
    with pytest.raises(RenderError, match="eglGetDisplay failed") as info:
        render_context.create_context()
    assert "libgl1-mesa-dri" in str(info.value)


def test_antialiasing_softens_only_the_silhouette_edges(gl_context, bar, helpers):
    """MSAA and FXAA change pixels near edges only, and add in-between shades there."""
    from scipy.ndimage import binary_dilation

    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(0.6), [1, 0, 0])])
    images = {}
    for name, options in {"none": dict(samples=0), "msaa": dict(samples=4), "fxaa": dict(samples=0, fxaa=True)}.items():
        with Renderer(V, F, W, width=160, height=120, camera=front_camera(), ground=False, background=BLACK,
                      context=gl_context, **options) as renderer:
            images[name] = renderer.draw(T).astype(int)
    mask = images["none"].max(axis=2) > 0
    edges = binary_dilation(mask, iterations=2) & binary_dilation(~mask, iterations=2)  # 2 px band
    for name in ("msaa", "fxaa"):
        changed = np.abs(images[name] - images["none"]).max(axis=2) > 24
        assert changed.sum() > 40  # the edges were smoothed...
        assert (changed & ~edges).sum() <= 3  # ...and nothing else was touched
    with pytest.raises(RenderInputError, match="fxaa: use it instead of MSAA"):
        Renderer(V, F, W, samples=4, fxaa=True, context=gl_context)


def test_draw_allocates_no_frame_sized_arrays(gl_context, bar, helpers):
    """Per frame: T into the preallocated uniform array, image into the preallocated buffer."""
    import tracemalloc

    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(0.5), [1, 0, 0])])
    bones = np.array([[[0.0, 0, 0], [1.0, 0, 0]], [[1.0, 0, 0], [2.0, 0, 0]]])
    for skinning in ("gpu", "cpu"):
        with Renderer(V, F, W, width=320, height=240, skinning=skinning, context=gl_context) as renderer:
            renderer.draw(T, bones=bones, bone_states=["sensed", "free"])  # warm up (first-use setup)
            tracemalloc.start()
            for _ in range(5):
                renderer.draw(T, bones=bones, bone_states=["sensed", "free"])
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
        assert peak < 16_000  # a 320x240 RGB frame alone is 230 kB; positions are 15 kB


def test_z_up_scene_renders_like_the_same_scene_y_up(gl_context, bar, helpers):
    """Ground, framing, lights and shadow follow `up`: rotating the world changes nothing."""
    V, F, W = bar
    y_to_z = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # rotation taking +y to +z
    pose = helpers.rotation_about(helpers.rotation_z(0.7), [1, 0, 0])
    T_y = helpers.handle_T([helpers.IDENTITY, pose])
    pose_z = np.hstack([y_to_z @ pose[:, :3] @ y_to_z.T, (y_to_z @ pose[:, 3])[:, None]])
    T_z = helpers.handle_T([helpers.IDENTITY, pose_z])
    with Renderer(V, F, W, width=160, height=120, context=gl_context) as renderer:
        image_y = renderer.draw(T_y).astype(float)
    with Renderer(V @ y_to_z.T, F, W, width=160, height=120, up=(0, 0, 1), context=gl_context) as renderer:
        image_z = renderer.draw(T_z).astype(float)
    assert np.abs(image_y - image_z).mean() < 1.5


def test_skeleton_overlay_accepts_an_object_with_heads_and_tails(gl_context, bar, helpers):
    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(0.4), [1, 0, 0])])

    class Skeleton:
        heads = np.array([[0.0, 0, 0], [1.0, 0, 0]])
        tails = np.array([[1.0, 0, 0], [2.0, 0, 0]])

    with Renderer(V, F, W, width=160, height=120, context=gl_context) as renderer:
        from_array = renderer.draw(T, bones=np.stack([Skeleton.heads, Skeleton.tails], 1)).astype(int)
        from_object = renderer.draw(T, bones=Skeleton()).astype(int)
        plain = renderer.draw(T).astype(int)
    assert np.abs(from_array - from_object).max() <= 2
    assert (np.abs(from_array - plain).max(axis=2) > 60).sum() > 30


def test_two_renderers_sharing_a_context_do_not_disturb_each_other(gl_context, bar, helpers):
    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.rotation_about(helpers.rotation_z(0.9), [1, 0, 0])])
    V2, F2 = helpers.tube(segments=12, sides=8, length=1.0, radius=0.4)
    W2 = np.ones((len(V2), 1))
    T2 = helpers.handle_T([helpers.rotation_about(helpers.rotation_z(0.3), [0, 0, 0])])
    with Renderer(V, F, W, width=96, height=72, context=gl_context) as first:
        alone = first.draw(T).copy()
        with Renderer(V2, F2, W2, width=64, height=64, samples=0, fxaa=True, context=gl_context) as second:
            second_alone = second.draw(T2).copy()
            for _ in range(2):
                interleaved = first.draw(T).copy()
                second_interleaved = second.draw(T2).copy()
                assert np.abs(interleaved.astype(int) - alone).max() <= 1
                assert np.abs(second_interleaved.astype(int) - second_alone).max() <= 1
        assert np.abs(first.draw(T).astype(int) - alone).max() <= 1  # after the other one's release


def test_fxaa_over_the_character_rectangle_equals_fxaa_over_the_frame(gl_context, posed_critter):
    """FXAA filters only the character's rectangle on screen (the ground fades out smoothly),
    blurring only the pixels its first pass marked as edges: the same image as one pass over
    the whole frame, and the silhouette is still smoothed."""
    rig, W, T, bones = posed_critter
    images = {}
    for name, options in {"frame": dict(fxaa=True, fxaa_region="frame", fxaa_passes="one_pass"),
                          "character": dict(fxaa=True, fxaa_region="character", fxaa_passes="mark_edges"),
                          "none": dict(fxaa=False)}.items():
        with Renderer(rig.V, rig.F, W, width=320, height=240, samples=0, context=gl_context, **options) as renderer:
            images[name] = renderer.draw(T, bones=bones).copy()
            if name == "character":
                x, y, w, h = renderer.antialias.rect
                assert 0 < w * h < 0.8 * 320 * 240  # a part of the frame, not all of it
    difference = np.abs(images["character"].astype(int) - images["frame"].astype(int)).max(axis=2)
    assert difference.max() <= 2
    smoothed = np.abs(images["character"].astype(int) - images["none"].astype(int)).max(axis=2) > 8
    assert smoothed.sum() > 100  # silhouette pixels blended by the filter


def test_vertex_lighting_looks_like_pixel_lighting_on_the_critter(gl_context, posed_critter):
    """Lit per vertex in the skinning pass (the default for closed meshes): on the critter's
    pixel-sized triangles the same image as lighting every fragment, within a few levels."""
    rig, W, T, bones = posed_critter
    images = {}
    for shading in ("pixel", "vertex"):
        with Renderer(rig.V, rig.F, W, samples=0, fxaa=True, context=gl_context, shading=shading) as renderer:
            assert renderer.shading == shading
            images[shading] = renderer.draw(T, bones=bones).copy()
            positions = renderer.skinned_positions(T).copy()
        images[shading + " positions"] = positions
    difference = np.abs(images["vertex"].astype(int) - images["pixel"].astype(int)).max(axis=2)
    assert difference.max() <= 48
    assert (difference > 8).mean() < 1e-3, (difference > 8).mean()
    assert (difference > 2).mean() < 1e-2, (difference > 2).mean()
    assert (difference > 0).any()  # the two paths did run: some pixels differ slightly
    np.testing.assert_array_equal(images["vertex positions"], images["pixel positions"])
    with Renderer(rig.V, rig.F, W, samples=0, context=gl_context) as renderer:
        assert renderer.shading == "vertex"  # auto, closed mesh with back faces culled
    with Renderer(rig.V, rig.F, W, samples=0, context=gl_context, cull_back_faces=False) as renderer:
        assert renderer.shading == "pixel"  # auto, both sides seen


def test_vertex_lighting_of_open_surfaces_is_refused(gl_context, bar):
    V, F, W = bar
    with pytest.raises(RenderInputError, match="shading: 'vertex' needs skinning='gpu' and cull_back_faces=True"):
        Renderer(V, F, W, context=gl_context, shading="vertex", cull_back_faces=False)
    with pytest.raises(RenderInputError, match="shading: expected one of"):
        Renderer(V, F, W, context=gl_context, shading="gouraud")


def test_each_camera_gets_its_own_backdrop_and_shadow(gl_context, bar, helpers):
    """The ground without its shadow is drawn once per camera and copied into each frame; a
    frame after camera switches (more cameras than backdrops kept) equals a fresh renderer's."""
    V, F, W = bar
    T = helpers.handle_T([helpers.IDENTITY, helpers.IDENTITY])
    cameras = [front_camera(), Camera(eye=[4.0, 3.0, 5.0], target=[1.0, 0.0, 0.0]),
               Camera(eye=[-3.0, 2.0, 4.0], target=[1.0, 0.0, 0.0])]
    fresh = []
    for camera in cameras:
        with Renderer(V, F, W, width=160, height=120, samples=0, camera=camera, context=gl_context) as r:
            fresh.append(r.draw(T).copy())
    with Renderer(V, F, W, width=160, height=120, samples=0, camera=cameras[0], context=gl_context) as r:
        for k in (0, 1, 0, 2, 1, 0, 2):
            r.camera = cameras[k]
            np.testing.assert_array_equal(r.draw(T), fresh[k], err_msg=f"camera {k}")
        assert len(r.ground_pass.backdrops) == 2
