"""Every step of docs/blender.md, done in Blender (``bpy``) by docs/blender_check.py, on the built-in
critter and on a seamed, textured character whose armature and mesh nodes are moved, turned
and scaled unevenly: what each step shows is compared with the solver's vertices, frame by
frame (max and RMS distance, % of the rest bounding-box diagonal), with the scene's rate and
range.

Exact formats (PC2, USD) must land within float32 rounding: EXACT_PCT. Skinned formats (glTF,
BVH driving the mesh) are linear blend skinning of the solve's joints, which only approximates
the FAST mesh: Blender must show the very figures that ``puppet export`` reports for that
skinning (within AGREE_PCT), and those must stay small (SKINNING_MAX_PCT).
"""

import numpy as np

EXACT_PCT = 1e-4  # % of the diagonal: float32 rounding of coordinates of a few units
AGREE_PCT = 1e-3  # Blender's skinning vs puppet's own evaluation of the same skinning
SKINNING_MAX_PCT = 5.0


def distances_pct(shown, vertices: np.ndarray) -> np.ndarray:
    """(N, n) distance of each shown vertex from the solver's, % of the diagonal."""
    assert vertices.shape == shown.expected.shape, (
        f"{shown.name}: Blender shows {vertices.shape} (frames, vertices, 3), "
        f"the solve has {shown.expected.shape}")
    return np.linalg.norm(vertices - shown.expected, axis=2) / shown.diagonal * 100


def figures(shown, step: str) -> tuple[float, float]:
    """(max, RMS) % of the diagonal of a step against the solve, printed for the record."""
    d = distances_pct(shown, shown.steps[step]["vertices"])
    worst, rms = float(d.max()), float(np.sqrt((d ** 2).mean()))
    print(f"{shown.name} {step}: max {worst:.3g} %, RMS {rms:.3g} % of the diagonal, "
          f"{len(d)} frames at {shown.steps[step]['fps']:g} fps")
    return worst, rms


def assert_frames_and_rate(shown, step: str) -> None:
    """The scene plays frames 1..N at the take's rate after the document's steps."""
    s = shown.steps[step]
    assert (s["fps"], s["frame_start"], s["frame_end"]) == (shown.fps, 1, shown.frames), step
    if "action_range" in s:
        assert tuple(s["action_range"]) == (1.0, float(shown.frames)), step


def test_gltf_shows_the_skinning_that_export_reports(shown):
    assert_frames_and_rate(shown, "gltf")
    assert shown.steps["gltf"]["bones"] == list(shown.joint_names)
    worst, rms = figures(shown, "gltf")
    assert abs(worst - shown.report["lbs_max_pct"]) <= AGREE_PCT
    assert abs(rms - shown.report["lbs_rms_pct"]) <= AGREE_PCT
    assert worst < SKINNING_MAX_PCT


def test_gltf_records_its_rate_and_range_for_blender(shown):
    """The importer turns the glTF scene's extras into the scene's custom properties: the rate
    to set and the range 1..N."""
    assert shown.steps["gltf"]["scene_properties"] == {
        "puppet_fps": shown.fps, "puppet_frame_start": 1, "puppet_frame_end": shown.frames}


def test_pc2_on_the_exported_glb_is_the_solve(shown):
    assert_frames_and_rate(shown, "pc2_glb")
    worst, _ = figures(shown, "pc2_glb")
    assert worst < EXACT_PCT


def test_usd_is_the_solve(shown):
    assert_frames_and_rate(shown, "usd")
    worst, _ = figures(shown, "usd")
    assert worst < EXACT_PCT


def test_bvh_drives_the_characters_own_mesh(shown):
    """The BVH's bones take over the mesh's Armature modifier: its vertex groups (the character
    file's joint names) find a bone each, and the mesh follows the solve's rigid joint maps."""
    assert_frames_and_rate(shown, "bvh")
    assert shown.steps["bvh"]["bones"] == list(shown.joint_names)
    assert set(shown.steps["bvh"]["vertex_groups"]) <= set(shown.steps["bvh"]["bones"])
    worst, _ = figures(shown, "bvh")
    assert worst < SKINNING_MAX_PCT
    shown_vertices = shown.steps["bvh"]["vertices"]
    assert shown_vertices.shape == shown.rigid_skinning.shape
    off = np.linalg.norm(shown_vertices - shown.rigid_skinning, axis=2) / shown.diagonal * 100
    assert off.max() < AGREE_PCT


def test_the_test_character_in_blender_is_the_rigs_rest_pose(mare_shown):
    """The builder's file, as Blender imports it, is what puppet read (the yardstick of the rest)."""
    rest = mare_shown.steps["pc2_source"]["rest"]
    assert rest.shape == mare_shown.expected.shape[1:]
    d = np.linalg.norm(rest - mare_shown.rest_expected, axis=1) / mare_shown.diagonal * 100
    assert d.max() < EXACT_PCT


def test_pc2_on_the_characters_own_import_is_the_solve(mare_shown):
    """The moved, turned, unevenly scaled character imported from its own file: the PC2 lands
    on it exactly (the points are in the mesh object's local space)."""
    assert_frames_and_rate(mare_shown, "pc2_source")
    worst, _ = figures(mare_shown, "pc2_source")
    assert worst < EXACT_PCT


def test_pc2_in_model_space_lands_as_on_an_object_without_transform(mare_shown, mare_model_space):
    """``--space model``: the points are the model frame's, so Blender's Mesh Cache puts them
    through the mesh object's transform once more: off by the armature's place on this
    character, exactly that transform applied to the solve."""
    M = mare_model_space["mesh_world"]
    placed_twice = mare_shown.expected @ M[:3, :3].T + M[:3, 3]
    off = np.linalg.norm(mare_model_space["vertices"] - placed_twice, axis=2) / mare_shown.diagonal * 100
    assert off.max() < EXACT_PCT
    assert distances_pct(mare_shown, mare_model_space["vertices"]).min() > 10.0


def test_gltf_keeps_the_characters_vertices_and_look(mare_shown):
    """The exported .glb comes back with the file's vertices (seam copies too), its UV sets,
    vertex colours, materials and texture."""
    gltf = mare_shown.steps["gltf"]
    assert gltf["vertices"].shape[1] == mare_shown.expected.shape[1]
    assert len(gltf["uv_layers"]) == 2
    assert len(gltf["color_attributes"]) == 1
    assert gltf["materials"] == ["coat", "hoof"]
    assert len(gltf["images"]) == 1


def test_gltf_puts_the_character_where_its_file_does(mare_shown):
    """The exported .glb's armature and mesh objects get the transforms of the character file's."""
    gltf, source = mare_shown.steps["gltf"], mare_shown.steps["pc2_source"]
    np.testing.assert_allclose(gltf["armature_world"], source["armature_world"], atol=1e-6)
    np.testing.assert_allclose(gltf["mesh_world"], source["mesh_world"], atol=1e-6)


def test_usd_keeps_the_characters_look(mare_shown):
    """The USD comes back with the file's UV sets, vertex colours, materials and texture."""
    usd = mare_shown.steps["usd"]
    assert (len(usd["uv_layers"]), len(usd["color_attributes"])) == (2, 1)
    assert usd["materials"] == ["coat", "hoof"]
    assert len(usd["images"]) == 1


def test_usdz_is_the_solve_with_its_texture_inside(mare_shown, mare_usdz):
    """``--usd anim.usdz``: one file with the texture packaged, imported the same way."""
    assert (mare_usdz["fps"], mare_usdz["frame_start"], mare_usdz["frame_end"]) == (
        mare_shown.fps, 1, mare_shown.frames)
    assert distances_pct(mare_shown, mare_usdz["vertices"]).max() < EXACT_PCT
    assert mare_usdz["materials"] == ["coat", "hoof"]
    assert len(mare_usdz["images"]) == 1

