"""Exports carry the character file's look and place: a glTF character whose armature and mesh
nodes are moved, turned and non-uniformly scaled, with a UV seam, two UV sets, vertex colours
and an embedded texture (the pillar of ``tests/rig/character.py``). The PC2 lands on it in the mesh object's
local space; the .glb keeps the file's vertices, attributes, material, image and nodes."""

import importlib.util
import subprocess
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation

from puppet.export import Outputs, export_take
from puppet.export.joint_transforms import JointTransforms
from puppet.rig import load_rig
from puppet.take import TakeReader

RIG = """name = "pillar"
mesh = "{mesh}"
fixed = ["root"]

[solver]
clusters = 8

[[servo]]
id = 2
model = "XL330-M288"
joint = "mid"
axis = "x"
zero_ticks = 2048
limits_deg = [-90, 90]

[[servo]]
id = 3
model = "XL330-M288"
joint = "top"
axis = "z"
zero_ticks = 2048
limits_deg = [-90, 90]
"""


def _module(name, path):
    spec = importlib.util.spec_from_file_location(f"export_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


characters = _module("character", Path(__file__).parents[1] / "rig" / "character.py")
shared = _module("conftest", Path(__file__).with_name("conftest.py"))
readers = _module("readers", Path(__file__).with_name("readers.py"))
accessor, node_matrix, node_worlds = readers.accessor, readers.node_matrix, readers.worlds
PILLAR = characters.pillar()


@pytest.fixture(scope="module")
def pillar(tmp_path_factory):
    """(rig, take path, reference solve, folder) of the moved, textured pillar."""
    folder = tmp_path_factory.mktemp("pillar")
    characters.write(folder / "pillar.glb", PILLAR)
    (folder / "pillar.toml").write_text(RIG.format(mesh="pillar.glb"))
    rig = load_rig(folder / "pillar.toml")
    take = shared.write_take(folder / "take.mcap", rig)
    return rig, take, shared.reference_solve(rig, take), folder


def test_pc2_lands_on_the_moved_turned_and_scaled_mesh_object(pillar):
    rig, take, reference, folder = pillar
    solved = reference.deformed[:, rig.source_index]  # the file's vertex order, model frame
    assert solved.shape[1] == len(PILLAR.file_vertices()) > len(rig.V)  # seam copies are kept
    # Blender's glTF importer parents the skinned mesh to the armature object with an identity
    # transform: the mesh object's local space is the Armature node's world.
    np.testing.assert_allclose(rig.source.object_world, PILLAR.armature_world(), atol=1e-12)

    export_take(rig, TakeReader(take), Outputs(pc2=folder / "object.pc2"), fps=shared.FPS)
    export_take(rig, TakeReader(take), Outputs(pc2=folder / "model.pc2"), fps=shared.FPS,
                space="model")
    export_take(rig, TakeReader(take), Outputs(pc2=folder / "z.pc2"), fps=shared.FPS, up="z")
    local = readers.read_pc2(folder / "object.pc2")[1].astype(np.float64)
    A = PILLAR.armature_world()
    np.testing.assert_allclose(local @ A[:3, :3].T + A[:3, 3], solved, atol=2e-5)
    np.testing.assert_allclose(readers.read_pc2(folder / "model.pc2")[1], solved, atol=2e-5)
    np.testing.assert_allclose(readers.read_pc2(folder / "z.pc2")[1],
                               np.stack([local[..., 0], -local[..., 2], local[..., 1]], -1), atol=1e-6)


def test_glb_keeps_the_files_vertices_attributes_material_and_nodes(pillar):
    rig, take, reference, folder = pillar
    out = folder / "anim.glb"
    report = export_take(rig, TakeReader(take), Outputs(gltf=out), fps=shared.FPS)
    assert report.warnings == []
    gltf = pygltflib.GLTF2().load_binary(str(out))
    source = pygltflib.GLTF2().load_binary(str(folder / "pillar.glb"))

    # Nodes: same order, names, hierarchy and rest transforms.
    assert [n.name for n in gltf.nodes] == [n.name for n in source.nodes]
    assert [n.children or [] for n in gltf.nodes] == [n.children or [] for n in source.nodes]
    assert [gltf.nodes[i].name for i in gltf.scenes[gltf.scene].nodes] == ["Armature"]
    for ours, theirs in zip(gltf.nodes, source.nodes):
        np.testing.assert_allclose(node_matrix(ours), node_matrix(theirs), atol=1e-6)
    armature = gltf.nodes[0]
    np.testing.assert_allclose(armature.translation, PILLAR.armature_trs[0])
    np.testing.assert_allclose(armature.scale, PILLAR.armature_trs[2])
    mesh_node = next(n for n in gltf.nodes if n.mesh is not None)
    assert mesh_node.name == "pillar" and mesh_node.skin == 0
    np.testing.assert_allclose(mesh_node.scale, PILLAR.mesh_trs[2])

    # The mesh: the file's primitives, vertex count and order, triangles, every attribute each
    # primitive had (and no other), its material.
    prims = PILLAR.primitives
    written = gltf.meshes[mesh_node.mesh].primitives
    assert [p.material for p in written] == [0, 1]
    for p, theirs in zip(written, prims):
        a = p.attributes
        np.testing.assert_allclose(accessor(gltf, a.POSITION), theirs["V"], atol=1e-5)
        np.testing.assert_array_equal(accessor(gltf, p.indices).reshape(-1, 3), theirs["F"])
        np.testing.assert_allclose(accessor(gltf, a.NORMAL), theirs["N"], atol=1e-6)
        np.testing.assert_array_equal(accessor(gltf, a.TEXCOORD_0), theirs["uv0"])
        for attribute, key in (("TEXCOORD_1", "uv1"), ("COLOR_0", "colours")):
            if theirs[key] is None:
                assert getattr(a, attribute) is None
            else:
                np.testing.assert_array_equal(accessor(gltf, getattr(a, attribute)), theirs[key])

    # The materials and the texture, the image embedded byte for byte.
    skin_material, cap = gltf.materials
    assert (skin_material.name, cap.name) == ("skin", "cap")
    assert cap.pbrMetallicRoughness.baseColorFactor == [0.2, 0.3, 0.9, 1.0]
    assert cap.pbrMetallicRoughness.baseColorTexture is None
    material = skin_material
    assert material.pbrMetallicRoughness.baseColorFactor == [1.0, 0.9, 0.8, 1.0]
    texture = gltf.textures[material.pbrMetallicRoughness.baseColorTexture.index]
    image = gltf.images[texture.source]
    assert image.mimeType == "image/png" and image.uri is None
    view = gltf.bufferViews[image.bufferView]
    assert gltf.binary_blob()[view.byteOffset:view.byteOffset + view.byteLength] == characters.png_bytes()
    assert gltf.samplers[texture.sampler].magFilter == 9728

    # The skin skins the rest mesh at rest (inverse bind matrices include the mesh node's world),
    # and every frame puts each joint's pivot where the solve puts it.
    skin = gltf.skins[0]
    assert [gltf.nodes[j].name for j in skin.joints] == list(rig.skeleton.names)
    ibm = accessor(gltf, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    rest = node_worlds(gltf, {i: node_matrix(n) for i, n in enumerate(gltf.nodes)})
    for k, j in enumerate(skin.joints):
        np.testing.assert_allclose(rest[j] @ ibm[k], PILLAR.mesh_world(), atol=1e-5)
    # Under the Armature's rotation and non-uniform scale the rotation keys are the nearest ones;
    # the pivots are exact all the same.
    joint_worlds_follow_the_solve(gltf, rig, reference)


def joint_worlds_follow_the_solve(gltf, rig, reference) -> float:
    """Evaluate the file's joints (its nodes, keys and hierarchy) at three frames: their pivots
    are where the solve puts them; returns the largest difference of their linear parts from
    the solve's rigid maps applied to the rest joints (0 where the keys are exact)."""
    skin = gltf.skins[0]
    anim = gltf.animations[0]
    keys = {(c.target.node, c.target.path): accessor(gltf, anim.samplers[c.sampler].output)
            for c in anim.channels}
    rest = node_worlds(gltf, {i: node_matrix(n) for i, n in enumerate(gltf.nodes)})
    joints = JointTransforms(rig.skeleton.heads)
    worst = 0.0
    for f in (0, len(reference.T) // 2, len(reference.T) - 1):
        joints.update(reference.T[f])
        locals_ = {i: node_matrix(n) for i, n in enumerate(gltf.nodes)}
        for j in skin.joints:
            scale = gltf.nodes[j].scale or [1, 1, 1]
            locals_[j] = readers.trs(keys[(j, "translation")][f], keys[(j, "rotation")][f], scale)
        world = node_worlds(gltf, locals_)
        pivots = np.array([world[j][:3, 3] for j in skin.joints])
        np.testing.assert_allclose(pivots, joints.pivot, atol=1e-5)
        for k, j in enumerate(skin.joints):
            expected = joints.world[k][:, :3] @ rest[j][:3, :3]
            worst = max(worst, float(np.abs(world[j][:3, :3] - expected).max()))
    return worst


def test_glb_keys_are_exact_under_a_uniformly_scaled_turned_armature(tmp_path):
    turned = ((0.4, -1.0, 2.5), tuple(Rotation.from_euler("xyz", [30, 50, -20], degrees=True).as_quat()),
              (1.5, 1.5, 1.5))
    characters.write(tmp_path / "pillar.glb", characters.pillar(moved=turned))
    (tmp_path / "pillar.toml").write_text(RIG.format(mesh="pillar.glb"))
    rig = load_rig(tmp_path / "pillar.toml")
    take = shared.write_take(tmp_path / "take.mcap", rig, readings=12)
    reference = shared.reference_solve(rig, take)
    report = export_take(rig, TakeReader(take), Outputs(gltf=tmp_path / "anim.glb",
                                                        pc2=tmp_path / "mesh.pc2"), fps=shared.FPS)
    gltf = pygltflib.GLTF2().load_binary(str(tmp_path / "anim.glb"))
    assert joint_worlds_follow_the_solve(gltf, rig, reference) < 1e-5
    assert report.lbs_max_pct < 1e-3  # the file's skin is the solve (rigid pillar, exact keys)
    A = characters.pillar(moved=turned).armature_world()
    local = readers.read_pc2(tmp_path / "mesh.pc2")[1].astype(np.float64)
    np.testing.assert_allclose(local @ A[:3, :3].T + A[:3, 3], reference.deformed[:, rig.source_index],
                               atol=2e-5)


def test_rig_without_transforms_writes_the_same_points_in_both_spaces(tmp_path):
    characters.write(tmp_path / "flat.glb", characters.pillar(moved=False))
    (tmp_path / "flat.toml").write_text(RIG.format(mesh="flat.glb"))
    rig = load_rig(tmp_path / "flat.toml")
    take = shared.write_take(tmp_path / "take.mcap", rig, readings=8)
    for space in ("object", "model"):
        export_take(rig, TakeReader(take), Outputs(pc2=tmp_path / f"{space}.pc2"), fps=10, space=space)
    assert (tmp_path / "object.pc2").read_bytes() == (tmp_path / "model.pc2").read_bytes()


def test_missing_image_file_warns_and_exports_a_plain_material(tmp_path):
    characters.write(tmp_path / "pillar.gltf", PILLAR, image_file=False)
    assert not (tmp_path / characters.PILLAR_IMAGE).exists()
    (tmp_path / "pillar.toml").write_text(RIG.format(mesh="pillar.gltf"))
    rig = load_rig(tmp_path / "pillar.toml")  # the rig loads all the same
    missing = str(tmp_path / characters.PILLAR_IMAGE)
    assert len(rig.source.warnings) == 1 and missing in rig.source.warnings[0]
    take = shared.write_take(tmp_path / "take.mcap", rig, readings=8)
    result = subprocess.run(["puppet", "export", str(take), "--rig", str(tmp_path / "pillar.toml"),
                             "--gltf", str(tmp_path / "anim.glb"), "--fps", "10"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert f"warning: {tmp_path / 'pillar.gltf'}: image file {missing!r}" in result.stderr
    gltf = pygltflib.GLTF2().load_binary(str(tmp_path / "anim.glb"))
    material, _ = gltf.materials
    assert material.name == "skin"
    assert material.pbrMetallicRoughness.baseColorTexture is None  # plain: its factors only
    assert material.pbrMetallicRoughness.baseColorFactor == [1.0, 0.9, 0.8, 1.0]
    assert gltf.images == [] and gltf.textures == []
    # With the image next to the .gltf, it is embedded.
    (tmp_path / characters.PILLAR_IMAGE).write_bytes(characters.png_bytes())
    rig = load_rig(tmp_path / "pillar.toml")
    assert rig.source.warnings == []
    export_take(rig, TakeReader(take), Outputs(gltf=tmp_path / "with.glb"), fps=10)
    gltf = pygltflib.GLTF2().load_binary(str(tmp_path / "with.glb"))
    assert len(gltf.images) == 1 and gltf.materials[0].pbrMetallicRoughness.baseColorTexture.index == 0


def _usd_mesh(stage):
    from pxr import UsdGeom

    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) == 1
    return UsdGeom.Mesh(meshes[0])


@pytest.mark.parametrize("suffix", [".usda", ".usdz"])
def test_usd_carries_the_files_place_uvs_colours_and_textured_material(pillar, suffix):
    from pxr import Usd, UsdGeom, UsdShade

    rig, take, reference, folder = pillar
    out = folder / f"anim{suffix}"
    report = export_take(rig, TakeReader(take), Outputs(usd=out), fps=shared.FPS)
    assert report.warnings == []
    stage = Usd.Stage.Open(str(out))
    mesh = _usd_mesh(stage)
    # The mesh sits under the Armature node's Xform (its TRS as written), as Blender's glTF
    # importer parents it; its points there, moved by its world transform, are the solve's.
    assert str(mesh.GetPath()) == "/pillar/Armature/pillar"
    armature = UsdGeom.Xformable(stage.GetPrimAtPath("/pillar/Armature"))
    assert [op.GetOpName() for op in armature.GetOrderedXformOps()] == [
        "xformOp:translate", "xformOp:orient", "xformOp:scale"]
    solved = reference.deformed[:, rig.source_index]
    for frame in (1, len(solved) // 2, len(solved)):
        time = Usd.TimeCode(frame)
        world = np.array(UsdGeom.XformCache(time).GetLocalToWorldTransform(mesh.GetPrim())).T
        np.testing.assert_allclose(world, PILLAR.armature_world(), atol=1e-6)
        local = np.array(mesh.GetPointsAttr().Get(time), np.float64)
        np.testing.assert_allclose(local @ world[:3, :3].T + world[:3, 3], solved[frame - 1], atol=2e-5)
        normals = np.array(mesh.GetNormalsAttr().Get(time))
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
        sides_n, rings_n = characters.PILLAR_SIDES, characters.PILLAR_RINGS
        ring = np.arange(0, rings_n * (sides_n + 1), sides_n + 1)  # u = 0
        np.testing.assert_allclose(normals[ring], normals[ring + sides_n], atol=1e-6)  # smooth
        caps = len(PILLAR.primitives[0]["V"]) + np.arange(sides_n)  # the bottom cap's ring
        assert np.abs(np.einsum("ij,ij->i", normals[caps], normals[:sides_n])).max() < 0.9  # hard
    # The file's triangles (its primitives in order), UV sets (t = 1 - v), colours.
    prims = PILLAR.primitives
    sides = len(prims[0]["V"])
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3),
                                  np.concatenate([prims[0]["F"], prims[1]["F"] + sides]))
    primvars = UsdGeom.PrimvarsAPI(mesh)
    for name, uv in (("st", np.concatenate([prims[0]["uv0"], prims[1]["uv0"]])), ("st1", prims[0]["uv1"])):
        st = np.array(primvars.GetPrimvar(name).Get())
        assert primvars.GetPrimvar(name).GetInterpolation() == "vertex"
        np.testing.assert_allclose(st[:len(uv)], np.column_stack([uv[:, 0], 1 - uv[:, 1]]), atol=1e-7)
    colours = prims[0]["colours"]
    shown = np.array(mesh.GetDisplayColorPrimvar().Get())
    np.testing.assert_allclose(shown[:sides], colours[:, :3])
    np.testing.assert_array_equal(shown[sides:], 1.0)  # the caps have no colours: white
    np.testing.assert_allclose(np.array(mesh.GetDisplayOpacityPrimvar().Get()),
                               np.concatenate([colours[:, 3], np.ones(len(shown) - sides)]))
    # Each primitive's material on its triangles (GeomSubsets).
    subsets = UsdShade.MaterialBindingAPI(mesh.GetPrim()).GetMaterialBindSubsets()
    bound = {UsdShade.MaterialBindingAPI(s.GetPrim()).ComputeBoundMaterial()[0].GetPath().name:
             np.array(s.GetIndicesAttr().Get()) for s in subsets}
    assert sorted(bound) == ["cap", "skin"]
    np.testing.assert_array_equal(bound["skin"], np.arange(len(prims[0]["F"])))
    np.testing.assert_array_equal(bound["cap"], len(prims[0]["F"]) + np.arange(len(prims[1]["F"])))
    cap = UsdShade.Material(stage.GetPrimAtPath("/pillar/Materials/cap")).ComputeSurfaceSource()[0]
    np.testing.assert_allclose(cap.GetInput("diffuseColor").Get(), [0.2, 0.3, 0.9])
    # The material: a UsdPreviewSurface whose diffuse colour is the texture, the image beside
    # the layer (or inside the .usdz) byte for byte.
    material = UsdShade.Material(stage.GetPrimAtPath("/pillar/Materials/skin"))
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
    (source,) = surface.GetInput("diffuseColor").GetConnectedSources()[0]
    texture = UsdShade.Shader(source.source.GetPrim())
    assert texture.GetIdAttr().Get() == "UsdUVTexture"
    np.testing.assert_allclose(texture.GetInput("scale").Get(), [1.0, 0.9, 0.8, 1.0])
    asset = texture.GetInput("file").Get()
    assert asset.resolvedPath != ""
    if suffix == ".usdz":
        import zipfile

        with zipfile.ZipFile(out) as package:
            names = package.namelist()
            assert names[0].endswith(".usdc")
            (image,) = [n for n in names if n.endswith(".png")]
            assert package.read(image) == characters.png_bytes()
    else:
        assert Path(asset.resolvedPath).read_bytes() == characters.png_bytes()
        assert Path(asset.resolvedPath).parent == folder / "anim_textures"
    assert surface.GetInput("roughness").Get() == pytest.approx(0.7)
    assert surface.GetInput("metallic").Get() == pytest.approx(0.0)


def test_usd_of_a_missing_image_has_a_plain_material(tmp_path):
    from pxr import Usd, UsdShade

    characters.write(tmp_path / "pillar.gltf", PILLAR, image_file=False)
    (tmp_path / "pillar.toml").write_text(RIG.format(mesh="pillar.gltf"))
    rig = load_rig(tmp_path / "pillar.toml")
    take = shared.write_take(tmp_path / "take.mcap", rig, readings=8)
    report = export_take(rig, TakeReader(take), Outputs(usd=tmp_path / "anim.usdc"), fps=10)
    assert len(report.warnings) == 1 and str(tmp_path / characters.PILLAR_IMAGE) in report.warnings[0]
    stage = Usd.Stage.Open(str(tmp_path / "anim.usdc"))
    surface = UsdShade.Material(stage.GetPrimAtPath("/pillar/Materials/skin")).ComputeSurfaceSource()[0]
    assert not surface.GetInput("diffuseColor").HasConnectedSource()
    np.testing.assert_allclose(surface.GetInput("diffuseColor").Get(), [1.0, 0.9, 0.8])
    assert not (tmp_path / "anim_textures").exists()


def test_unusable_attribute_is_left_out_with_a_warning(tmp_path):
    path = characters.write(tmp_path / "pillar.gltf", PILLAR)
    doc = pygltflib.GLTF2().load(str(path))
    sides = doc.meshes[0].primitives[0].attributes
    sides.TEXCOORD_1 = sides.NORMAL  # three components: not a UV set
    doc.meshes[0].primitives[0].attributes.COLOR_0 = len(doc.accessors) + 5  # no such accessor
    doc.save_json(str(path))
    (tmp_path / "pillar.toml").write_text(RIG.format(mesh="pillar.gltf"))
    rig = load_rig(tmp_path / "pillar.toml")  # the rig needs neither: it loads
    texcoord, colour = sorted(rig.source.warnings, key=lambda w: "TEXCOORD_1" not in w)
    n = len(PILLAR.primitives[0]["V"])
    assert f"primitives[0].TEXCOORD_1: {n} values of 3 for {n} vertices" in texcoord
    assert "COLOR_0" in colour and "does not exist" in colour and str(path) in colour
    assert set(rig.source.attributes) == {"NORMAL", "TEXCOORD_0"}
    take = shared.write_take(tmp_path / "take.mcap", rig, readings=6)
    report = export_take(rig, TakeReader(take), Outputs(gltf=tmp_path / "anim.glb"), fps=10)
    assert report.warnings == rig.source.warnings
    gltf = pygltflib.GLTF2().load_binary(str(tmp_path / "anim.glb"))
    written = gltf.meshes[0].primitives[0].attributes
    assert written.TEXCOORD_1 is None and written.COLOR_0 is None and written.TEXCOORD_0 is not None


def test_image_gone_after_the_rig_loaded_is_named_by_both_exporters(tmp_path):
    """SourceImage.read: the one way an exporter reads a texture; a file deleted since the rig
    loaded gives each exporter the same warning naming it, and plain materials."""
    from pxr import Usd, UsdShade

    characters.write(tmp_path / "pillar.gltf", PILLAR)
    (tmp_path / "pillar.toml").write_text(RIG.format(mesh="pillar.gltf"))
    rig = load_rig(tmp_path / "pillar.toml")
    assert rig.source.warnings == []
    (tmp_path / characters.PILLAR_IMAGE).unlink()
    take = shared.write_take(tmp_path / "take.mcap", rig, readings=6)
    missing = str(tmp_path / characters.PILLAR_IMAGE)
    for outputs in (Outputs(gltf=tmp_path / "anim.glb"), Outputs(usd=tmp_path / "anim.usda")):
        report = export_take(rig, TakeReader(take), outputs, fps=10)
        assert len(report.warnings) == 1
        assert report.warnings[0].startswith(f"{missing}: cannot read the image")
        assert "left out" in report.warnings[0]
    gltf = pygltflib.GLTF2().load_binary(str(tmp_path / "anim.glb"))
    assert gltf.images == [] and gltf.materials[0].pbrMetallicRoughness.baseColorTexture is None
    stage = Usd.Stage.Open(str(tmp_path / "anim.usda"))
    surface = UsdShade.Material(stage.GetPrimAtPath("/pillar/Materials/skin")).ComputeSurfaceSource()[0]
    assert not surface.GetInput("diffuseColor").HasConnectedSource()
