"""PC2 of a take in the character file's own vertex order (a seam-split file), and its axes."""

import importlib.util
from pathlib import Path

import numpy as np
import pygltflib

from puppet.bus import Reading
from puppet.export import Outputs, export_take
from puppet.rig import Rig, ServoMap
from puppet.take import TakeReader, TakeWriter

_spec = importlib.util.spec_from_file_location("export_pc2_order_readers", Path(__file__).with_name("readers.py"))
readers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readers)


def seam_split(critter, rng):
    """The critter as a loader would give it for a file that split vertices at seams: the file
    lists every vertex once, shuffled, plus second copies of 500 of them."""
    n = len(critter.V)
    copies = rng.choice(n, 500, replace=False)
    source_index = np.concatenate([rng.permutation(n), copies])
    rng.shuffle(source_index)
    rig = Rig(name=critter.name, V=critter.V, F=critter.F, skeleton=critter.skeleton, W=critter.W,
              servo_map=ServoMap(critter.servo_map.servos), calibration=critter.calibration,
              solver_options=critter.solver_options, pins=critter.pins, fixed=critter.fixed,
              source_index=source_index)
    return rig, source_index


def test_pc2_follows_the_source_files_vertex_order(tmp_path, critter, take30, reference):
    rig, source_index = seam_split(critter, np.random.default_rng(11))
    assert len(source_index) == len(critter.V) + 500
    file_vertices = critter.V[source_index]  # what the seam-split file holds, in its order

    # A take that starts at the rest pose: sample 1 is the file's own rest vertices.
    rest = tmp_path / "rest.mcap"
    k = len(rig.servo_map)
    with TakeWriter(rest, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
        for i in range(3):
            ticks = (rig.servo_map.zero + (0 if i == 0 else 300)).astype(np.int32)
            writer.write(Reading(i * 100_000_000, rig.servo_map.ids, ticks, np.ones(k, bool)))
    out, glb = tmp_path / "rest.pc2", tmp_path / "rest.glb"
    export_take(rig, TakeReader(rest), Outputs(pc2=out, gltf=glb), fps=10)
    header, points = readers.read_pc2(out)
    start, rate = header["start_frame"], header["sample_rate"]
    assert (start, rate) == (1.0, 1.0)
    assert points.shape == (3, len(source_index), 3)
    np.testing.assert_allclose(points[0], file_vertices, atol=1e-5)
    # The exported glTF lists the same vertices in the same order (a PC2 fits a mesh made from it).
    gltf = pygltflib.GLTF2().load_binary(str(glb))
    position = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION]
    view = gltf.bufferViews[position.bufferView]
    stored = np.frombuffer(gltf.binary_blob(), np.float32, count=3 * position.count,
                           offset=view.byteOffset).reshape(-1, 3)
    np.testing.assert_array_equal(stored, file_vertices.astype(np.float32))

    # A moving take: every sample is the solve's mesh, listed in the file's order.
    out = tmp_path / "moving.pc2"
    export_take(rig, TakeReader(take30), Outputs(pc2=out), fps=24)
    _, points = readers.read_pc2(out)
    assert len(points) == len(reference.times_ns)
    np.testing.assert_allclose(points, reference.deformed[:, source_index], atol=2e-6)


def test_up_z_turns_the_y_up_model_for_blender(tmp_path, critter, take30, reference):
    out = tmp_path / "z.pc2"
    export_take(critter, TakeReader(take30), Outputs(pc2=out), fps=24, up="z")
    _, points = readers.read_pc2(out)
    ref = reference.deformed
    expected = np.stack([ref[..., 0], -ref[..., 2], ref[..., 1]], -1)
    np.testing.assert_allclose(points, expected, atol=2e-6)
