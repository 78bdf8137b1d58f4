"""BVH joints keep the rig's names (dots, .L/.R, punctuation; whitespace -> _) and leaf End
Sites reach the mesh: checked on the file and in Blender 5.0 itself (``bpy``, in a subprocess)."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from puppet.export import BvhWriter, Outputs, export_take, mesh_end_sites
from puppet.export.names import safe_name, safe_names
from puppet.rig import load_rig
from puppet.rig.init_file import write_rig_init
from puppet.take import TakeReader


def load_module(relative: str):
    """A test helper module by path (pytest runs with --import-mode=importlib: no packages)."""
    path = Path(__file__).parents[1] / relative
    spec = importlib.util.spec_from_file_location("export_names_" + path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


read_bvh = load_module("export/readers.py").read_bvh
write_take = load_module("export/conftest.py").write_take

blender = load_module("export/blender/run_bpy.py")  # Blender (bpy) in a subprocess
needs_bpy = pytest.mark.skipif(blender.bpy_missing() is not None, reason=str(blender.bpy_missing()))

#: Names Blender's BVH importer must keep exactly: mirroring suffixes, punctuation, and the
#: BVH format's own words and braces as joint names.
KEPT = ["hips", "leg.L", "leg.R", "foot.L", "foot.R", "spine.001", "a{b}", "}", "{", "End",
        "Site", "MOTION", "Frames:", "x#y", 'q"uote', "a/b", "a\\b", "a,b;c", "[0]", "-1"]


IMPORT_BVH = """
import bpy, json, sys
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=sys.argv[1])
arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
bones = {b.name: b.length for b in arm.data.bones}
groups = []
if len(sys.argv) > 2:
    bpy.ops.import_scene.gltf(filepath=sys.argv[2])
    body = next(o for o in bpy.data.objects if o.type == "MESH")
    groups = [g.name for g in body.vertex_groups]
print("RESULT " + json.dumps({"bones": bones, "groups": groups}))
"""


def test_the_bvh_rule_keeps_everything_but_whitespace():
    assert [safe_name(n, "bvh") for n in KEPT] == KEPT
    assert safe_names(["tail base", "tail_base", "a\tb", "ünter", "日本", ""], "bvh") == (
        ["tail_base_2", "tail_base", "a_b", "unter", "__", "_"],
        {"tail base": "tail_base_2", "a\tb": "a_b", "ünter": "unter", "日本": "__", "": "_"})
    # USD paths: identifiers only (a second rule of the same module).
    assert safe_names(["leg.L", "1st"], "usd") == (["leg_L", "_1st"], {"leg.L": "leg_L", "1st": "_1st"})


@needs_bpy
def test_blender_imports_every_kept_name_unchanged(tmp_path):
    path = tmp_path / "names.bvh"
    b = len(KEPT)
    offsets = np.tile([0.0, 1.0, 0.0], (b, 1))
    with BvhWriter(path, names=KEPT, parents=np.arange(b) - 1, offsets=offsets,
                   frame_time=1 / 24) as writer:
        writer.write(np.tile(np.eye(3), (b, 1, 1)))
    assert read_bvh(path.read_text()).names == KEPT
    bones = blender.run_bpy_result(IMPORT_BVH, path)["bones"]
    assert sorted(bones) == sorted(KEPT)


def test_end_sites_follow_the_vertices_each_leaf_moves_most():
    """A chain root -> a (leaf along +x) and root -> b (leaf of no length, frame +Y = +z) and
    c (a leaf no vertex follows most): a reaches its farthest vertex along the bone, not the
    farthest from its pivot; b's points along its frame's +Y; c keeps the rig's tail."""
    heads = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0]], float)
    tails = np.array([[0, 0.5, 0], [1.2, 0, 0], [0, 1, 0], [0, -1.3, 0]], float)
    frames = np.tile(np.eye(3), (4, 1, 1))
    frames[2] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # columns x, y = +z, z
    V = np.array([[1.7, 0.0, 0.0], [1.5, 0.9, 0.0], [0.1, 1.0, 0.6], [0.0, 1.0, -0.2], [0.2, 0.0, 0.0]])
    W = np.array([[0.1, 0.9, 0, 0], [0.2, 0.8, 0, 0], [0, 0, 1, 0], [0.3, 0, 0.7, 0], [1, 0, 0, 0]])
    ends = mesh_end_sites(heads, tails, frames, np.array([-1, 0, 0, 0]), V, W)
    np.testing.assert_allclose(ends, [[0, 0.5, 0], [0.7, 0, 0], [0, 0, 0.6], [0, -0.3, 0]])


@pytest.fixture(scope="module")
def beast(tmp_path_factory):
    """The glTF character with three servos, a take of it, and its glTF + BVH export."""
    character = load_module("rig/character.py")  # leg.L, foot.L, 'tail base'...
    folder = tmp_path_factory.mktemp("beast")
    glb = character.write_glb(folder / "beast.glb")
    rig_path, _ = write_rig_init(glb)
    servos = {"neck": {"id": 4}, "tail base": {"id": 5, "axis": '"z"'}, "leg.L": {"id": 9}}
    rig_path.write_text(character.enable_servos(rig_path.read_text(), servos))
    rig = load_rig(rig_path)
    take = write_take(folder / "beast.mcap", rig, readings=12)
    out = {"gltf": folder / "out.glb", "bvh": folder / "out.bvh"}
    report = export_take(rig, TakeReader(take), Outputs(**out), fps=24)
    return character, glb, out, report


def test_bvh_joint_names_are_the_gltf_joint_names(beast):
    character, _, out, report = beast
    bvh_names = read_bvh(out["bvh"].read_text()).names
    gltf = pygltflib.GLTF2().load_binary(str(out["gltf"]))
    gltf_names = [gltf.nodes[j].name for j in gltf.skins[0].joints]
    assert sorted(gltf_names) == sorted(character.NAMES)
    assert sorted(bvh_names) == sorted(n.replace(" ", "_") for n in gltf_names)
    assert {"leg.L", "foot.L", "hips"} <= set(bvh_names)
    assert report.renamed == {"bvh": {"tail base": "tail_base", "tail tip": "tail_tip"}}


def test_end_sites_reach_the_farthest_vertex_of_each_leaf(beast):
    _, _, out, _ = beast
    end_sites = read_bvh(out["bvh"].read_text()).end_sites
    # The character's geometry (tests/rig/character.py): the body tube runs from z = -0.7 to 1.8,
    # the leg tube down to y = -0.7; each leaf's pivot and bone direction are known.
    expected = {"head": (0.0, 0.0, 1.8 - 1.4), "tail_tip": (0.0, 0.0, -0.7 + 0.5),
                "foot.L": (0.0, -0.7 + 0.35, 0.0)}
    assert sorted(end_sites) == sorted(expected)
    for name, offset in expected.items():
        np.testing.assert_allclose(end_sites[name], offset, atol=1e-5)


@needs_bpy
def test_blender_bones_match_the_vertex_groups_and_the_mesh(beast):
    _, _, out, _ = beast
    got = blender.run_bpy_result(IMPORT_BVH, out["bvh"], out["gltf"])
    bvh_names = read_bvh(out["bvh"].read_text()).names
    assert sorted(got["bones"]) == sorted(bvh_names)
    # Every joint without whitespace drives the vertex group of the same name, unrenamed.
    unchanged = {n for n in got["groups"] if " " not in n}
    assert unchanged and unchanged <= set(got["bones"])
    for leaf, length in (("head", 0.4), ("tail_tip", 0.2), ("foot.L", 0.35)):
        assert math.isclose(got["bones"][leaf], length, abs_tol=1e-5)


NAMES_BACK = """
import bpy, json, sys
zip_path, bvh, glb = sys.argv[-3:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module="puppet_link")
bpy.ops.import_scene.gltf(filepath=glb)
body = next(o for o in bpy.data.objects if o.type == "MESH")
before = set(bpy.data.objects)
bpy.ops.import_anim.bvh(filepath=bvh)
arm = next(o for o in bpy.data.objects if o not in before and o.type == "ARMATURE")
imported = sorted(b.name for b in arm.data.bones)
bpy.ops.object.select_all(action="DESELECT")
body.select_set(True)
arm.select_set(True)
bpy.context.view_layer.objects.active = arm
assert bpy.ops.puppet_link.bvh_names() == {"FINISHED"}
modifier = next(m for m in body.modifiers if m.type == "ARMATURE")
modifier.object = arm  # the docs' step: the mesh follows the BVH's armature
action = arm.animation_data.action
paths = sorted({c.data_path.split('"')[1] for layer in action.layers for strip in layer.strips
                for bag in strip.channelbags for c in bag.fcurves if '"' in c.data_path})
turned = {}
for frame in (1, 6, 12):
    bpy.context.scene.frame_set(frame)
    turned[frame] = arm.pose.bones["tail base"].matrix_basis.to_quaternion().angle
print("RESULT " + json.dumps({"imported": imported, "bones": sorted(b.name for b in arm.data.bones),
                              "groups": [g.name for g in body.vertex_groups], "paths": paths,
                              "turned": turned}))
"""


@needs_bpy
def test_the_addon_gives_the_bvh_bones_their_names_with_spaces_back(beast, tmp_path):
    """Blender's BVH importer joins a name's words with "_" (so puppet writes "tail base" as
    "tail_base"); the add-on's "BVH names back" renames those bones to the character's spelling
    by puppet's rule, the action's channels follow, and every vertex group finds its bone: the
    "tail base" joint, which a servo turns, drives its vertex group."""
    from puppet.link.addon import write_addon

    _, _, out, _ = beast
    addon = write_addon(tmp_path / "puppet_link.zip")
    got = blender.run_bpy_result(NAMES_BACK, addon, out["bvh"], out["gltf"])
    assert {"tail_base", "tail_tip"} <= set(got["imported"])
    assert {"tail base", "tail tip"} <= set(got["bones"])
    assert not {"tail_base", "tail_tip"} & set(got["bones"])
    assert set(got["groups"]) <= set(got["bones"]), (got["groups"], got["bones"])
    assert set(got["paths"]) <= set(got["bones"]) and "tail base" in got["paths"]
    assert max(got["turned"].values()) > 1e-3  # the servo's joint moves under its own name
