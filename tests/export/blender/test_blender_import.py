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


def test_reduced_keys_play_in_blender_within_the_tolerance(critter_shown, critter_keyed):
    """``--keys 0.5``: Blender's own evaluation of the reduced glTF, every bone on every frame,
    stays within the tolerances of the key-per-frame glTF (the solved curve), with the keys
    that the report lists and far fewer than one per frame."""
    keys, full, reduced = critter_keyed.report["keys"], critter_shown.steps["gltf"], critter_keyed.gltf
    assert (reduced["fps"], reduced["frame_start"], reduced["frame_end"]) == (
        critter_shown.fps, 1, critter_shown.frames)
    assert tuple(reduced["action_range"]) == (1.0, float(critter_shown.frames))
    dot = np.abs(np.einsum("fbi,fbi->fb", full["pose_rotations"], reduced["pose_rotations"]))
    angle = np.degrees(2 * np.arccos(np.clip(dot, 0.0, 1.0)))
    moved = np.linalg.norm(full["pose_locations"] - reduced["pose_locations"], axis=2)
    print(f"--keys 0.5: Blender holds {reduced['keys']} of {full['keys']} key values; worst "
          f"{angle.max():.3f}° and {moved.max():.3g} units off the solved curves")
    assert angle.max() <= keys["rotation_deg"] + 1e-3
    assert moved.max() <= keys["translation_units"] + 1e-6
    per_joint = keys["joints"].values()
    assert reduced["keys"] == sum(4 * j["rotation"] + 3 * j["translation"] for j in per_joint)
    assert reduced["keys"] < full["keys"] / 2
