"""puppet rig init on a skinned glTF character built in the test, the journey after it
(fill servo ids -> rig info -> hw-sim -> record -> play), and bad glTF input."""

import json
import os
import signal
import subprocess
import tomllib

import imageio_ffmpeg
import numpy as np
import pytest

from puppet.rig import RigError, load_rig
from puppet.rig.gltf import read_gltf
from puppet.take import TakeReader


def run(*args, timeout=180):
    return subprocess.run(["puppet", *map(str, args)], capture_output=True, text=True, timeout=timeout)


def assert_error(result, *fragments):
    """A clean CLI failure: exit 1, one 'Error:' line naming what is wrong, no traceback."""
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith("Error: ")
    for fragment in fragments:
        assert fragment in error


def test_init_writes_every_joint_with_axes_in_words(tmp_path, character):
    glb = character.write_glb(tmp_path / "beast.glb")
    result = run("rig", "init", glb, "--out", tmp_path / "beast.toml")
    assert result.returncode == 0, result.stderr
    text = (tmp_path / "beast.toml").read_text()
    doc = tomllib.loads(text)
    assert doc["name"] == "beast" and doc["mesh"] == "beast.glb"
    assert doc["fixed"] == ["hips"]
    assert doc["solver"]["clusters"] >= len(character.NAMES)
    assert doc["solver"]["energy"] == "spokes_and_rims"
    assert "servo" not in doc  # the blocks are commented for the user to fill
    for name, parent, _, _ in character.BONES:
        words = "root, no parent" if parent is None else f"parent {parent!r}"
        assert f"# joint {name!r} ({words})" in text
        assert f'# joint = "{name}"' in text
    assert text.count("# [[servo]]") == len(character.NAMES)
    # Blender-style bones: local y along the bone, x to the character's left.
    lines = text.splitlines()
    leg = lines.index("# joint 'leg.L' (parent 'hips')")
    assert lines[leg + 1] == "#   rest axes: x: to the character's left, y: down along the bone, z: backward"
    assert lines[leg + 2] == ("#   turning +x swings the tip backward, +y twists it, "
                              "+z swings the tip to the character's right")
    tail = lines.index("# joint 'tail base' (parent 'hips')")
    assert lines[tail + 1] == "#   rest axes: x: to the character's left, y: backward along the bone, z: up"

    info = run("rig", "info", tmp_path / "beast.toml", "--json")
    assert info.returncode == 0, info.stderr
    report = json.loads(info.stdout)
    assert report["bones"] == len(character.NAMES)
    assert report["servos"] == 0
    assert report["file_vertices"] == len(character.rest_vertices(split=True))
    assert report["vertices"] == len(character.rest_vertices(split=False))
    assert report["full"] == ["hips"]


def test_init_refuses_to_overwrite_without_force(tmp_path, character):
    glb = character.write_glb(tmp_path / "beast.glb")
    rig = tmp_path / "beast.toml"
    rig.write_text("# my rig, hand edited\n")
    assert_error(run("rig", "init", glb), "beast.toml: exists; pass --force")
    assert rig.read_text() == "# my rig, hand edited\n"
    result = run("rig", "init", glb, "--force")
    assert result.returncode == 0, result.stderr
    assert rig.read_text().startswith("# Rig for beast.glb")
    assert_error(run("rig", "init", glb, "--out", glb, "--force"), "is also an input")  # even forced
    assert_error(run("rig", "init", glb, "--out", tmp_path / "beast.txt"), "rig file ends in .toml")


def test_character_to_take_and_video(tmp_path, character):
    """rig init -> ids filled -> rig info -> hw-sim serving those ids -> record -> play --rig."""
    glb = character.write_glb(tmp_path / "beast.glb")
    rig = tmp_path / "beast.toml"
    assert run("rig", "init", glb).returncode == 0
    servos = {"neck": {"id": 4}, "tail base": {"id": 5, "axis": '"z"', "sign": -1}, "leg.L": {"id": 9}}
    rig.write_text(character.enable_servos(rig.read_text(), servos))
    info = run("rig", "info", rig, "--json")
    assert info.returncode == 0, info.stderr
    report = json.loads(info.stdout)
    assert report["servos"] == 3
    assert sorted(report["full"]) == ["hips", "leg.L", "tail base"]
    assert report["relative"] == ["neck"]  # under the free spine

    take, video = tmp_path / "take.mcap", tmp_path / "take.mp4"
    sim = subprocess.Popen(["hw-sim", "--servos", "4,5,9", "--motion", "wave"], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        port = sim.stdout.readline().strip()
        assert port.startswith("/dev/"), sim.stderr.read() if sim.poll() is not None else port
        result = run("record", "--rig", rig, "--port", port, "--out", take, "--seconds", 1, "--rate", 200)
        assert result.returncode == 0, result.stderr
    finally:
        sim.send_signal(signal.SIGTERM)
        sim.wait(timeout=60)
    reader = TakeReader(take)
    assert reader.metadata.rig_name == "beast"
    readings = list(reader.readings())
    assert len(readings) >= 5
    ticks = np.stack([r.ticks for r in readings])
    assert np.ptp(ticks, axis=0).min() > 0, ticks  # every servo moved (by little when starved)

    result = run("play", take, "--rig", rig, "--out", video, "--speed", 4.0)
    assert result.returncode == 0, result.stderr
    assert imageio_ffmpeg.count_frames_and_secs(str(video))[0] >= 1


def test_init_with_two_skins_needs_skin(tmp_path, character):
    doc, blob = character.build(skins=2)
    doc.set_binary_blob(blob)
    doc.save_binary(str(tmp_path / "two.glb"))
    assert_error(run("rig", "init", tmp_path / "two.glb"),
                 "two.glb: skins: 2 skins are used by meshes: 0 ('Armature'), 1 ('Second'); choose one with --skin N")
    result = run("rig", "init", tmp_path / "two.glb", "--skin", 1)
    assert result.returncode == 0, result.stderr
    rig = tmp_path / "two.toml"
    assert tomllib.loads(rig.read_text())["skin"] == 1
    loaded = load_rig(rig)
    twin = read_gltf(tmp_path / "two.glb", skin=1)
    assert len(loaded.V) == len(twin.V) < len(read_gltf(tmp_path / "two.glb", skin=0).V)


def test_joint_without_vertices_is_held_fixed(tmp_path, character):
    glb = character.write_glb(tmp_path / "jaw.glb", extra_joint="jaw")
    result = run("rig", "init", glb)
    assert result.returncode == 0, result.stderr
    assert "warning: " in result.stderr and "joint 'jaw' influences no vertex" in result.stderr
    rig = tmp_path / "jaw.toml"
    assert tomllib.loads(rig.read_text())["fixed"] == ["hips", "jaw"]
    assert load_rig(rig).bone_kinds()["relative"] == ["jaw"]
    # Left free, it is an error at load that names it (the solve could not place it).
    rig.write_text(rig.read_text().replace('fixed = ["hips", "jaw"]', 'fixed = ["hips"]'))
    assert_error(run("rig", "info", rig), "jaw.toml: fixed: bones ['jaw'] influence no vertex")


def _save(doc, blob, path):
    doc.set_binary_blob(blob)
    doc.save_binary(str(path))
    return path


def test_bad_gltf_input_names_the_file_and_the_fault(tmp_path, character):
    doc, blob = character.build()
    doc.nodes[-1].skin = None
    doc.skins = []
    assert_error(run("rig", "init", _save(doc, blob, tmp_path / "noskin.glb")),
                 "noskin.glb: skins: no skin: 1 mesh(es) and 0 skin(s)")

    singular = np.eye(4)
    singular[:3, :3] = np.diag([1.0, 0.0, 1.0])
    doc, blob = character.build(ibm_override={"tail base": singular})
    assert_error(run("rig", "init", _save(doc, blob, tmp_path / "ibm.glb")),
                 "ibm.glb: skins[0].inverseBindMatrices[4] (joint 'tail base'): not invertible")

    fake = tmp_path / "photo.glb"
    fake.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    assert_error(run("rig", "init", fake), "photo.glb: not a glTF binary: a .glb starts with 'glTF'")
    fake.write_bytes(b"glTF" + (1).to_bytes(4, "little") + bytes(32))
    assert_error(run("rig", "init", fake), "photo.glb: glTF binary version 1; only glTF 2.0 is read")
    json_file = tmp_path / "notes.gltf"
    json_file.write_text('{"hello": "world"}')
    assert_error(run("rig", "init", json_file), "notes.gltf: asset: not a glTF file: no 'asset'")
    assert_error(run("rig", "init", tmp_path / "missing.glb"), "missing.glb: glTF file not found")
    assert not any(p.suffix == ".toml" for p in tmp_path.iterdir())  # nothing written on failure

    with pytest.raises(RigError, match=r"skin 3 does not exist: the file has 1 skin"):
        read_gltf(character.write_glb(tmp_path / "ok.glb"), skin=3)


def test_welded_source_index_maps_the_file_order(tmp_path, character):
    split = read_gltf(character.write_glb(tmp_path / "split.glb", split=True))
    whole = read_gltf(character.write_glb(tmp_path / "whole.glb", split=False))
    assert whole.source_index is None and whole.file_vertices == len(whole.V)
    file_positions = character.rest_vertices(split=True)
    assert split.file_vertices == len(file_positions) > len(split.V)
    np.testing.assert_allclose(split.V[split.source_index], file_positions, atol=1e-6)
    # Every welded vertex comes from a file vertex, and the rig keeps the map.
    assert set(split.source_index.tolist()) == set(range(len(split.V)))
    rig = load_rig(tmp_path / "split.glb")
    np.testing.assert_array_equal(rig.source_index, split.source_index)
    assert os.path.getsize(tmp_path / "split.glb") > os.path.getsize(tmp_path / "whole.glb")
