"""The add-on in Blender (``bpy``, in a subprocess): installed and enabled from the zip that
``puppet blender addon`` writes, connected to ``puppet play TAKE --link``, it poses the glTF
import of the critter so that every recorded frame equals ``puppet export --gltf`` of the same
take (bone heads and tails, world, within 1e-5 of the rest diagonal), and the mesh mode shows
the solver's vertices."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
SCRIPT = HERE / "blender_link.py"


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


run_bpy = _load("link_run_bpy", HERE.parent / "export" / "blender" / "run_bpy.py")
helpers = _load("link_blender_helpers", HERE / "helpers.py")
Y_UP_TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@pytest.fixture(scope="module", autouse=True)
def needs_bpy():
    reason = run_bpy.bpy_missing()
    if reason:
        pytest.skip(reason)


@pytest.fixture(scope="module")
def addon_zip(tmp_path_factory):
    out = tmp_path_factory.mktemp("addon") / "puppet_link.zip"
    done = subprocess.run(["puppet", "blender", "addon", "--out", str(out)], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return out


def _blender(addon_zip, glb, take, mesh, wait_until, interrupt_and_wait):
    puppet = helpers.Puppet(["play", take, "--link", "127.0.0.1:0", "--speed", "0.25"])
    try:
        port, _ = puppet.listening(wait_until)
        result = run_bpy.run_bpy_result(SCRIPT.read_text(), addon_zip, glb, port, int(mesh))
        assert puppet.proc.wait(timeout=300) == 0
    finally:
        interrupt_and_wait(puppet.proc, read_stderr=False)
    return result, puppet


def test_recorded_keys_equal_the_gltf_export_frame_by_frame(
        addon_zip, exported, take, critter, wait_until, interrupt_and_wait):
    result, puppet = _blender(addon_zip, exported["glb"], take, False, wait_until,
                              interrupt_and_wait)
    diagonal = float(np.linalg.norm(critter.V.max(0) - critter.V.min(0)))
    assert result["notes"][0].startswith(f"{len(critter.skeleton.names)} of "), result["notes"]
    assert "stopped streaming" in result["status"]  # puppet's bye: the last pose stays
    assert result["malformed"] == 0
    frames = result["frames"]
    assert len(frames) >= 3, result
    worst = max(f["worst"] for f in frames)
    assert worst <= 1e-5 * diagonal, frames
    assert any("reading->applied median" in line for line in puppet.out), puppet.out


def test_mesh_mode_writes_the_solvers_vertices(addon_zip, exported, take, critter, wait_until,
                                               interrupt_and_wait):
    result, _ = _blender(addon_zip, exported["glb"], take, True, wait_until, interrupt_and_wait)
    reference = helpers.reference_vertices(critter, take)
    assert result["meshes"], result
    diagonal = float(np.linalg.norm(critter.V.max(0) - critter.V.min(0)))
    for shown in result["meshes"]:
        k = round(shown["take_s"] * 30)
        expected = reference[k] @ Y_UP_TO_BLENDER.T
        assert np.abs(np.array(shown["world"]) - expected).max() <= 1e-5 * diagonal, k


def _fake_puppet(critter, listener):
    """Serve one client as a puppet would, then stop without a bye: a hello whose rig has one
    joint more than the critter's armature, a malformed frame, then a frame with the second
    joint turned 90° about x."""
    from puppet.link import wire
    from puppet.link.pose import LinkPose

    pose = LinkPose(critter, lbs=None)
    sock, _ = listener.accept()
    with sock:
        reader = wire.Reader()
        while True:
            reader.feed(sock.recv(4096))
            messages = list(reader.messages())
            if messages:
                break
        names = [*pose.names, "extra_joint"]
        t = [*pose.rest_translations.tolist(), [0.0, 0.1, 0.0]]
        q = [*pose.rest_rotations.tolist(), [0.0, 0.0, 0.0, 1.0]]
        sock.sendall(wire.encode_json(wire.HELLO, {
            "protocol": wire.PROTOCOL, "rig": "critter", "joints": names,
            "parents": [*pose.parents, 0], "rest_translation": t, "rest_rotation": q,
            "vertices": pose.n_vertices, "fps": 30.0, "take_start_ns": 0}))
        good = wire.encode_frame(0, 0, 0.0, t, [q[0], [0.70710678, 0.0, 0.0, 0.70710678], *q[2:]])
        bad = bytearray(good)
        wire.LENGTH.pack_into(bad, 0, len(good) - wire.LENGTH.size - 8)  # 8 bytes short
        sock.sendall(bytes(bad[:-8]) + good)
        while sock.recv(4096):  # until the add-on acks (then it closes)
            break


def test_the_addon_reports_refusal_mapping_problems_malformed_frames_and_a_stop(
        addon_zip, exported, take, critter, wait_until, interrupt_and_wait):
    import socket
    import threading

    refusing = helpers.Puppet(["play", take, "--link", "0.0.0.0:0"])
    listener = socket.create_server(("127.0.0.1", 0))
    server = threading.Thread(target=_fake_puppet, args=(critter, listener), daemon=True)
    server.start()
    try:
        port, token = refusing.listening(wait_until)
        result = run_bpy.run_bpy_result((HERE / "blender_edges.py").read_text(), addon_zip,
                                        exported["glb"], port, listener.getsockname()[1])
    finally:
        interrupt_and_wait(refusing.proc, read_stderr=False)
        listener.close()
    b = len(critter.skeleton.names)
    assert result["refused_status"] == "refused: token refused: give the token puppet printed"
    first = result["first_bone"]
    assert result["notes"][:3] == [
        f"{b - 1} of {b + 1} joints drive bones",
        f"joint {first}: no bone 'no_such_bone' (saved mapping); not driven",
        "joint extra_joint: no bone 'extra_joint' (same name); not driven"], result["notes"]
    assert result["notes"][3] == f"1 bones not driven: {first}"
    assert (result["malformed"], result["applied"]) == (1, 1)
    assert result["status"] == "puppet stopped streaming; last pose kept"
    assert result["posed"] == result["kept"]
    assert np.abs(np.array(result["posed"]) - np.eye(4)).max() > 0.5  # the 90° turn applied
