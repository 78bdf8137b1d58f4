"""The add-on in Blender (``bpy``, in a subprocess): installed and enabled from the zip that
``puppet blender addon`` writes, connected to ``puppet play TAKE --link``, the mesh mode shows
the solver's vertices, a moved, turned and scaled armature is driven as its export plays, the
add-on reports what goes wrong, and ``live --record --link`` keys where the export puts each
frame. (Recording from ``play``, the point cache, the user's mesh kept and reconnection:
``test_blender_session.py``.)"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

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


def _blender(addon_zip, glb, take, mesh, wait_until, interrupt_and_wait, rig_file=None):
    rig = [] if rig_file is None else ["--rig", rig_file]
    puppet = helpers.Puppet(["play", take, "--link", "127.0.0.1:0", "--speed", "0.25", *rig])
    try:
        port, _ = puppet.listening(wait_until)
        result = run_bpy.run_bpy_result(SCRIPT.read_text(), addon_zip, glb, port, int(mesh))
        assert puppet.proc.wait(timeout=300) == 0
    finally:
        interrupt_and_wait(puppet.proc, read_stderr=False)
    return result, puppet


def _mesh_mode(addon_zip, glb, take, rig, wait_until, interrupt_and_wait, rig_file=None):
    result, _ = _blender(addon_zip, glb, take, True, wait_until, interrupt_and_wait, rig_file)
    reference = helpers.reference_vertices(rig, take)
    order = np.arange(len(rig.V)) if rig.source_index is None else np.asarray(rig.source_index)
    assert result["meshes"], result
    diagonal = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    for shown in result["meshes"]:
        k = round(shown["take_s"] * 30)
        expected = reference[k][order] @ Y_UP_TO_BLENDER.T
        assert np.abs(np.array(shown["world"]) - expected).max() <= 1e-5 * diagonal, k


def test_mesh_mode_writes_the_solvers_vertices(addon_zip, exported, take, critter, wait_until,
                                               interrupt_and_wait):
    _mesh_mode(addon_zip, exported["glb"], take, critter, wait_until, interrupt_and_wait)


def test_a_moved_turned_scaled_armature_is_driven_as_its_gltf_export_plays(
        addon_zip, mare, wait_until, interrupt_and_wait):
    """The mare's armature node is moved, turned and scaled unevenly, its mesh node too: the
    bones follow the export's keys in the importer's space, and the mesh mode's vertices land
    where the solver puts them in the world."""
    rig = mare["rig"]
    result, _ = _blender(addon_zip, mare["glb"], mare["take"], False, wait_until,
                         interrupt_and_wait, mare["rig_file"])
    diagonal = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    b = len(rig.skeleton.names)
    assert result["notes"] == [f"{b} of {b} joints drive bones"], result["notes"]
    assert len(result["frames"]) >= 3, result
    assert max(f["worst"] for f in result["frames"]) <= 1e-5 * diagonal, result["frames"]
    assert max(f["moved"] for f in result["frames"]) > 0.01 * diagonal  # the bones did move
    _mesh_mode(addon_zip, mare["glb"], mare["take"], rig, wait_until, interrupt_and_wait,
               mare["rig_file"])


HEALTH = {"applied_median_ms": 12.5, "applied_p99_ms": 40.0, "acked": 1, "published": 1,
          "sent": 1, "skipped": 0, "lost": 3, "acked_per_s": 29.5}  # the fake puppet's word


def _fake_puppet(critter, listener):
    """Serve one client as a puppet would, then stop without a bye: a hello whose rig has one
    joint more than the critter's armature, a malformed frame, then a frame with the second
    joint turned 90° about x; once it is acked a health message (HEALTH) and no frame more (a
    stalled link) until the client asks for every frame (its Record ticked)."""
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
        healthy = False
        while True:
            data = sock.recv(4096)
            if not data:
                break
            reader.feed(data)
            kinds = [kind for kind, _ in reader.messages()]
            if wire.ACK_KIND in kinds and not healthy:
                healthy = True
                sock.sendall(wire.encode_json(wire.HEALTH, HEALTH))
            if wire.MESH in kinds:  # Record ticked: stop without a word
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
    assert result["health_lines"][:3] == [
        "reading->applied median 12.5 ms, p99 40.0 ms; applied 29.5/s",
        "LOST 3 recorded frames (Blender too far behind)",
        result["health_lines"][2]], result["health_lines"]  # puppet's figures, as it sent them
    assert result["health_lines"][2].startswith("stalled: no frame from puppet for ")
    assert result["status"] == "puppet stopped streaming; last pose kept"
    assert result["posed"] == result["kept"]
    assert np.abs(np.array(result["posed"]) - np.eye(4)).max() > 0.5  # the 90° turn applied


def _readings_around(take, rig, streamed, fps: float, start: int):
    """Where ``puppet export --fps FPS`` of ``take`` and the add-on's keys come from the same
    readings. Returns (at, ok, solved, elsewhere): per reading of the take its scene frame on
    the export's time line (start + play time x fps), whether every servo was read, whether
    puppet streamed it (a streamed frame on that scene frame); and the streamed frames on no
    reading's scene frame."""
    from puppet.take import TakeReader
    from puppet.take.playback import play_times_ns

    t_ns, _ticks, ok = TakeReader(take).arrays(rig.servo_map.ids)
    at = start + play_times_ns(t_ns)[0] * 1e-9 * fps
    streamed = np.asarray(streamed, float)
    nearest = np.clip(np.searchsorted(at, streamed), 1, len(at) - 1)
    nearest = np.where(np.abs(at[nearest - 1] - streamed) < np.abs(at[nearest] - streamed),
                       nearest - 1, nearest)
    on_reading = np.abs(at[nearest] - streamed) <= 1e-6
    solved = np.zeros(len(at), bool)
    solved[nearest[on_reading]] = True
    return at, ok.all(1), solved, streamed[~on_reading].tolist()


def _same_readings(frame: int, at, ok, solved) -> bool:
    """Whether the export's frame ``frame`` and the add-on's key there interpolate the same two
    readings (one, on a reading), at most a scene frame apart, each with every servo read."""
    i = int(np.searchsorted(at, frame + 1e-6, side="right")) - 1
    if i < 0:
        return False
    j = i if at[i] >= frame - 1e-6 else i + 1
    return (j < len(at) and at[j] - at[i] <= 1.0 and bool(solved[i] and solved[j])
            and bool(ok[i] and ok[j]))


def test_live_record_keys_blender_where_the_takes_export_puts_each_frame(
        addon_zip, exported, critter, tmp_path, wait_until, interrupt_and_wait):
    """``puppet live --record TAKE --link`` on hw_sim (the demo's motion) with Blender connected
    and Record off in the panel: puppet's frames are flagged recording, the add-on keys every
    integer scene frame from them (a frame at start + (reading time - the take's first reading)
    x scene fps; between two readings their blend), LINEAR, and every frame puppet streamed is
    a reading of the take at the scene frame ``puppet export --gltf`` of the take puts it on
    (an offset, or a wrong take start, moves them all). Blender's action agrees with the export
    at every scene frame where both interpolate the same two readings, at most a frame apart
    (the add-on blends keys, the export each servo's ticks: alike over a small turn): each
    sensed joint's rotation within a tenth of what the export turns it in one frame plus two
    encoder ticks (the export rounds interpolated ticks). Elsewhere the export interpolates readings puppet
    recorded but never solved (live solves the newest of each batch the bus gives), and on a
    loaded host hw_sim answers some reads late: such a reading sits up to a frame's turn off the
    line through its neighbours (a reading stamped before its read, the position sampled when
    the simulator got to it), so the two differ by as much, by design; a reading with a servo
    not read holds that servo's last good value, so the turn to the next reading is a jump, too
    large for a blend of keys and a blend of ticks to agree (2.7 degrees apart at one such
    frame, 43 degrees turned). The free bones are not compared:
    FAST solves them warm-started from the frame before (every reading live, every 1/30 s in the
    export), so they differ by how far each run's iterations got, not by time. Performed to a
    sound (``--sound``, 0.3 s into it at time 0): its strip lands 9 frames before the take's
    start."""
    import hw_sim
    from puppet.demo import Performance
    from puppet.rig.load import BUILTIN_RIG

    take, reference = tmp_path / "take.mcap", tmp_path / "reference.glb"
    sound = tmp_path / "line.wav"  # performed to: its strip lands 0.3 s (9 frames) before frame 1
    sf.write(sound, np.zeros((44100, 1), np.float32), 44100)
    with hw_sim.serve(critter.servo_map.models, motion=Performance(critter)) as bus:
        # 57600 bit/s: the SDK's reply timeout (the reply's bytes at the bus speed + 2 latencies
        # + 2 ms) is tens of ms, not a few as at 1 Mbit/s, so a busy host's late simulator
        # replies still count (a reading with a servo not read holds its last value: no frame
        # the export and the add-on both interpolate from it is compared)
        puppet = helpers.Puppet(["live", "--rig", BUILTIN_RIG, "--port", bus.port, "--baud",
                                 "57600", "--record", take, "--link", "127.0.0.1:0", "--sound",
                                 sound, "--sound-offset", "0.3"])
        try:
            port, _ = puppet.listening(wait_until)
            sensed = ",".join(s.joint for s in critter.servo_map.servos)
            blender = helpers.Puppet.python(["-c", (HERE / "blender_record.py").read_text(),
                                             addon_zip, exported["glb"], port, "150", reference,
                                             sensed])
            wait_until(lambda: "RECORDED" in blender.out or blender.proc.poll() is not None,
                       timeout=600)
            assert "RECORDED" in blender.out, "\n".join(blender.lines[-30:])
        finally:
            interrupt_and_wait(puppet.proc, read_stderr=False)
    assert puppet.proc.returncode == 0, "\n".join(puppet.lines)
    staged = tmp_path / "staged.glb"
    done = subprocess.run(["puppet", "export", str(take), "--gltf", str(staged), "--fps", "30"],
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    staged.rename(reference)
    assert blender.proc.wait(timeout=600) == 0, "\n".join(blender.lines[-30:])
    result = json.loads(next(x for x in blender.out if x.startswith("RESULT "))[len("RESULT "):])
    (tmp_path / "result.json").write_text(json.dumps(result))
    assert result["sound_strips"] == [{"name": "puppet sound", "frame_start": 1 - 9,
                                       "path": str(sound.absolute())}], result["sound_strips"]
    keyed = result["keyed"]
    assert keyed == list(range(keyed[0], keyed[-1] + 1))  # every integer frame, no holes
    assert result["interpolation"] == ["LINEAR"]
    assert result["action"] == "take"  # its own action, named after the take
    at, ok, solved, elsewhere = _readings_around(take, critter, result["streamed"], 30.0, 1)
    assert elsewhere == [], elsewhere  # every streamed frame where the export puts its reading
    compared = [f for f in result["frames"] if _same_readings(f["frame"], at, ok, solved)]
    (tmp_path / "compared.json").write_text(json.dumps(compared))
    assert len(compared) >= 6, (len(compared), result["lost"], result["frames"])
    tick_deg = 360.0 / 4096  # the critter's XL330s
    for f in compared:
        assert f["worst_deg"] <= 0.1 * f["step_deg"] + 2 * tick_deg, (f, compared)
    assert max(f["step_deg"] for f in compared) > 1.0  # the servos were moving
