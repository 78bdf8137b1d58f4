"""The add-on in one Blender session across two takes (``blender_session.py``, one ``bpy``
subprocess for the module), driving the critter as the README brings it into Blender
(``puppet blender character``): the user's mesh is never written, a recording has no holes through
a 1.5 s Blender stall and equals ``puppet export`` of the take, each take is its own action,
the add-on reconnects by itself, the panel reports the link's health, and a take's sound lands
on the scene's timeline where the take starts."""

from __future__ import annotations

import importlib.util
import json
import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

HERE = Path(__file__).resolve().parent


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


run_bpy = _load("session_run_bpy", HERE.parent / "export" / "blender" / "run_bpy.py")
helpers = _load("session_helpers", HERE / "helpers.py")
readers = _load("session_pc2_readers", HERE.parent / "export" / "readers.py")
suite = _load("session_suite_conftest", HERE.parent / "conftest.py")  # wait_until, for a module
wait_until, interrupt_and_wait = suite.wait_until, suite._interrupt_and_wait
suite_data = _load("session_export_data", HERE.parent / "export" / "conftest.py")
STALL_AFTER = 8  # frames applied before Blender stalls 1.5 s
SOUND_OFFSET_S = 0.5  # the second take's time 0 in its sound: 15 frames at the scene's 30 fps


@pytest.fixture(scope="module", autouse=True)
def needs_bpy():
    reason = run_bpy.bpy_missing()
    if reason:
        pytest.skip(reason)


@pytest.fixture(scope="module")
def session(tmp_path_factory, take, exported, critter):
    """The Blender session's RESULT, the point cache it wrote and the take's PC2 export."""
    folder = tmp_path_factory.mktemp("session")
    addon = folder / "puppet_link.zip"
    done = subprocess.run(["puppet", "blender", "addon", "--out", str(addon)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    character = folder / "critter.glb"  # the README's way to the built-in critter
    done = subprocess.run(["puppet", "blender", "character", "--out", str(character)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    from puppet.sound import load_sound, sound_ref

    sound_path = folder / "line.wav"  # the second take's sound, its time 0 0.5 s into it
    sf.write(sound_path, np.zeros((48000, 1), np.float32), 48000)
    second = suite_data.write_take(folder / "take2.mcap", critter, readings=46,
                                   sound=sound_ref(load_sound(sound_path), offset_s=SOUND_OFFSET_S))
    with socket.socket() as probe:  # a free port both puppets take in turn
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    cache = folder / "live_{take}.pc2"
    blender = helpers.Puppet.python(["-c", (HERE / "blender_session.py").read_text(), addon,
                                     character, exported["glb"], port, cache, STALL_AFTER])
    puppets = []
    try:
        for which, mark in ((take, "WAITING"), (second, "TAKE1")):
            if mark is not None:
                wait_until(lambda: mark in blender.out or blender.proc.poll() is not None,
                           timeout=600)
                assert mark in blender.out, "\n".join(blender.lines[-30:])
            puppet = helpers.Puppet(["play", which, "--link", f"127.0.0.1:{port}", "--speed",
                                     "0.5"])
            puppets.append(puppet)
            puppet.listening(wait_until)
            assert puppet.proc.wait(timeout=600) == 0, "\n".join(puppet.lines)
        assert blender.proc.wait(timeout=600) == 0, "\n".join(blender.lines[-30:])
    finally:
        for puppet in puppets:
            interrupt_and_wait(puppet.proc, read_stderr=False)
        interrupt_and_wait(blender.proc, read_stderr=False)
    result = json.loads(next(x for x in blender.out if x.startswith("RESULT "))[len("RESULT "):])
    (folder / "result.json").write_text(json.dumps(result, indent=1))
    pc2 = folder / "export.pc2"
    done = subprocess.run(["puppet", "export", str(take), "--pc2", str(pc2), "--up", "z", "--fps",
                           "30"], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    return {"result": result, "cache": folder / "live_take.pc2", "pc2": pc2, "puppets": puppets,
            "sound": sound_path}


def test_the_users_mesh_is_as_imported_after_disconnect(session):
    """Exact mesh on, toggled off and on mid-stream, two takes, Disconnect: the mesh's vertex
    coordinates (bytes), its modifiers (every property), shape keys, visibility, and the scene's
    objects and meshes are what they were before Connect; meanwhile the exact mesh was on the
    add-on's copy with the user's object hidden."""
    result = session["result"]
    assert result["after"] == result["before"]
    assert result["before"]["modifiers"][0]["type"] == "ARMATURE"
    during = result["during"]
    assert during["copy"].endswith("(puppet)") and during["hidden"] == [True, True]
    assert during["copy"] not in result["after"]["objects"]


def test_a_recording_has_a_linear_key_per_exported_frame_through_a_stall(session, exported,
                                                                          critter):
    """Blender stalled 1.5 s mid-take: still one key per frame of ``puppet export --gltf`` of
    the take (46 at 30 fps) on every channel, LINEAR on the keyframe points, and every frame
    within 1e-4 of the diagonal of the export (bone heads and tails, world)."""
    result = session["result"]
    frames_exported = exported["report"]["frames"]
    first = result["actions"][result["first"]]
    b = len(critter.skeleton.names)
    assert first["curves"] == 7 * b
    assert first["keys"] == [frames_exported]
    assert first["frames"] == [float(f) for f in range(1, frames_exported + 1)]
    assert first["interpolation"] == ["LINEAR"]
    assert first["paths"] == [".location", ".rotation_quaternion"]
    diagonal = float(np.linalg.norm(critter.V.max(0) - critter.V.min(0)))
    worst = max(f["worst"] for f in result["frames"])
    assert len(result["frames"]) == frames_exported
    assert worst <= 1e-4 * diagonal, result["frames"]
    assert any(line.startswith("Blender was busy") for line in result["during"]["stall_lines"])


def test_the_point_cache_equals_puppets_pc2_export_at_every_frame(session, critter):
    header, samples = readers.read_pc2(session["cache"])
    reference_header, reference = readers.read_pc2(session["pc2"])
    assert header["num_points"] == reference_header["num_points"] == len(critter.V)
    assert header["start_frame"] == reference_header["start_frame"] == 1
    assert len(samples) == len(reference)
    diagonal = float(np.linalg.norm(critter.V.max(0) - critter.V.min(0)))
    assert np.abs(samples - reference).max() <= 1e-5 * diagonal


def test_each_take_is_its_own_action_and_the_addon_reconnects_by_itself(session, exported):
    """Connect before puppet runs: the add-on waits and retries; the second puppet on the same
    port is picked up without a click, into a second action named after its take; the first
    action keeps its keys."""
    result = session["result"]
    states = result["states"]
    assert states[:3] == ["connecting", "waiting", "connecting"], states
    assert states.index("connected") > states.index("waiting")
    assert states[-1] == "connected" and "waiting" in states[states.index("TAKE1"):], states
    assert result["first"] == "take"
    assert set(result["actions"]) >= {"take", "take2"}, result["actions"].keys()
    frames_exported = exported["report"]["frames"]
    assert result["actions"]["take"]["keys"] == [frames_exported] == [
        result["first_keys_at_take1"]]
    second = result["actions"]["take2"]  # Record went off after 10 frames applied
    assert second["frames"] == [float(f) for f in range(1, len(second["frames"]) + 1)]
    assert 10 <= len(second["frames"]) < frames_exported
    assert result["malformed"] == 0
    assert result["notes"][0] == "18 of 18 joints drive bones", result["notes"]


def test_the_panel_shows_latency_rate_and_a_stall(session):
    panel = set(session["result"]["panel"])
    assert {"reading->applied", "Blender", "recording", "dropping"} <= panel, panel


def test_a_takes_sound_lands_on_the_timeline_where_the_take_starts(session):
    """The second take has a sound (its time 0 at 0.5 s): its strip, named "puppet sound",
    starts 15 frames (at 30 fps) before the take's start frame 1; the first take, without
    sound, took away the strip of that name an earlier take had left."""
    result = session["result"]
    assert result["strips_at_take1"] == [], result["strips_at_take1"]
    assert result["strips"] == [{"name": "puppet sound", "frame_start": 1 - 15,
                                 "path": str(session["sound"].absolute())}], result["strips"]
