"""Welding the copies a glTF exporter splits at seams: the welded character is the never-split
one (same vertices, triangles, weights, solve), and it renders without a crease on the seam."""

import subprocess

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.loop import Pipeline
from puppet.rig import Rig, load_rig
from puppet.rig.gltf import read_gltf
from puppet.rig.weld import weld_index, weld_mesh

SERVOS = {"neck": {"id": 4}, "tail base": {"id": 5, "axis": '"z"'}, "leg.L": {"id": 9}}
TICKS = np.array([2400, 1700, 2500], np.int32)  # neck, tail base, leg.L: turns of 31°, -30°, 40°


def test_weld_index_needs_same_position_and_weights():
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0], [0, 0, 1e-9], [1, 0, 0], [0, 0, 0]], float)
    W = np.array([[1, 0], [1, 0], [1, 0], [1, 0], [0.5, 0.5], [1, 0]])
    # 2, 3 (within tolerance) and 5 are copies of 0; 4 shares 1's position, not its weights.
    np.testing.assert_array_equal(weld_index(P, W), [0, 1, 0, 0, 2, 0])
    np.testing.assert_array_equal(weld_index(P[:2], W[:2]), [0, 1])
    F = np.array([[0, 1, 4], [0, 2, 1], [3, 4, 1], [4, 5, 1], [1, 4, 2]])
    V, F, Wo = weld_mesh(P, F, W, weld_index(P, W))
    # [0, 2, 1] collapses (0 and 2 weld); [4, 5, 1] and [1, 4, 2] become rotations of the first,
    # [0, 1, 2] (dropped); [3, 4, 1] becomes its back face [0, 2, 1] (kept).
    np.testing.assert_array_equal(F, [[0, 1, 2], [0, 2, 1]])
    np.testing.assert_array_equal(V, P[[0, 1, 4]])
    np.testing.assert_array_equal(Wo, W[[0, 1, 4]])


def test_welded_mesh_is_the_never_split_mesh(tmp_path, character):
    split = read_gltf(character.write_glb(tmp_path / "split.glb", split=True))
    whole = read_gltf(character.write_glb(tmp_path / "whole.glb", split=False))
    assert split.file_vertices > len(split.V)
    np.testing.assert_allclose(split.V, whole.V, atol=1e-12)
    np.testing.assert_array_equal(split.F, whole.F)
    np.testing.assert_allclose(split.W, whole.W, atol=1e-12)


def _solve(rig, readings=3):
    with Pipeline(rig, render=False) as pipeline:
        for _ in range(readings):
            pipeline.solve(Reading(0, rig.servo_map.ids, TICKS, np.ones(len(TICKS), bool)))
        return pipeline.deformed().copy()


def _rig(tmp_path, character, name, split):
    character.write_glb(tmp_path / f"{name}.glb", split=split)
    subprocess.run(["puppet", "rig", "init", tmp_path / f"{name}.glb"], check=True, capture_output=True,
                   timeout=120)
    rig = tmp_path / f"{name}.toml"
    rig.write_text(character.enable_servos(rig.read_text(), SERVOS))
    return load_rig(rig)


def test_welded_mesh_solves_like_the_never_split_mesh(tmp_path, character):
    welded = _rig(tmp_path, character, "split", True)
    whole = _rig(tmp_path, character, "whole", False)
    assert whole.source_index is None and len(welded.source_index) > len(welded.V)
    solved = _solve(welded)
    reference = _solve(whole)
    assert np.abs(reference - whole.V).max() > 0.2  # the servos really moved the character
    np.testing.assert_allclose(solved, reference, atol=1e-9)
    # In the file's own order (what point caches write), each copy follows its welded vertex.
    np.testing.assert_allclose(solved[welded.source_index], reference[welded.source_index], atol=1e-9)

    # The file's split mesh, solved as it is, is a different problem: the energy sees a cut (its
    # converged pose is a few 1e-6 off, float32 noise being about 1e-7).
    prims = character.mesh(split=True)
    offsets = np.cumsum([0] + [len(V) for V, _, _ in prims])
    F_file = np.concatenate([F + o for (_, F, _), o in zip(prims, offsets)])
    cut = Rig("cut", character.rest_vertices(split=True), F_file, welded.skeleton,
              welded.W[welded.source_index], welded.servo_map, welded.calibration, welded.solver_options,
              fixed=welded.fixed)
    assert np.abs(_solve(cut) - reference[welded.source_index]).max() > 1e-6


@pytest.fixture
def seam_renderer(character):
    """render(V, F, W) -> (h, w) brightness of the body seen square-on at its seam: the seam
    (angle 0 of the body tube, the character's left side at mid height) is the middle row."""
    from puppet.render import Camera, Renderer

    y = character.ARMATURE_OFFSET[1]
    camera = Camera(eye=[3.0, y, 0.5], target=[0.0, y, 0.5], up=[0, 1, 0], fov_deg=20)

    def render(V, F, W):
        T = np.tile(np.vstack([np.eye(3), np.zeros((1, 3))]), (W.shape[1], 1)).astype(np.float32)
        with Renderer(V, F, W, width=200, height=200, samples=0, ground=False, camera=camera) as renderer:
            return renderer.draw(T).astype(np.float64).mean(axis=2)

    return render


def test_welded_seam_renders_without_a_crease(tmp_path, character, seam_renderer):
    rig = load_rig(character.write_glb(tmp_path / "split.glb", split=True))
    column = seam_renderer(rig.V, rig.F, rig.W)[80:121, 100]  # 20 rows either side of the seam
    steps = np.abs(np.diff(column))
    assert column.min() > 60  # the body fills the window: the steps are shading, not edges
    assert steps.max() <= 4.0  # smooth shading across the seam: no step above the gradient's

    # The file as exported (copies apart) has a crease exactly there: the test can see one.
    prims = character.mesh(split=True)
    offsets = np.cumsum([0] + [len(V) for V, _, _ in prims])
    F_file = np.concatenate([F + o for (_, F, _), o in zip(prims, offsets)])
    raw = seam_renderer(character.rest_vertices(split=True), F_file, rig.W[rig.source_index])[80:121, 100]
    raw_steps = np.abs(np.diff(raw))
    assert raw_steps.max() > 20.0
    assert abs(int(np.argmax(raw_steps)) - 20) <= 1  # at the seam, the middle row


def test_meshes_sharing_one_skin_are_read_together(tmp_path, character):
    """Two nodes skinned by the same skin (Blender: two objects on one armature) are one character;
    the same mesh placed twice welds onto itself."""
    import pygltflib as g

    doc, blob = character.build()
    doc.meshes.append(g.Mesh(name="leg only", primitives=doc.meshes[0].primitives[1:]))
    doc.nodes += [g.Node(name="again", mesh=0, skin=0), g.Node(name="leg", mesh=1, skin=0)]
    doc.scenes[0].nodes += [len(doc.nodes) - 2, len(doc.nodes) - 1]
    doc.set_binary_blob(blob)
    doc.save_binary(str(tmp_path / "many.glb"))
    many = read_gltf(tmp_path / "many.glb")
    one = read_gltf(character.write_glb(tmp_path / "one.glb"))
    assert many.file_vertices == 2 * one.file_vertices + len(character.mesh()[1][0])
    np.testing.assert_allclose(many.V, one.V, atol=1e-12)
    np.testing.assert_array_equal(many.F, one.F)
