"""Layers recorded through the terminal on hw_sim with the real SDK: the legs in pass 1, the
arms over them in pass 2 (the base's servos driven, torque on, the arms' sensors in hand); the
exported glTF has pass 1's legs, pass 2's arms and free bones solved from both; torque read back
off on every stop path; the refusals."""

from __future__ import annotations

import importlib.util
import math
import queue
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pygltflib import GLTF2
from scipy.spatial.transform import Rotation

import hw_sim
from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_AX_RIG, BUILTIN_RIG
from puppet.take import TakeReader, TakeWriter
from puppet.take.header import take_header
from puppet.take.sync import SoundRef
from tests.layers.layer_takes import lag_s, raw_copy

_spec = importlib.util.spec_from_file_location(
    "layers_gltf_readers", Path(__file__).parents[1] / "export" / "readers.py")
readers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readers)

ARMS = "upperarm_L,forearm_L,upperarm_R,forearm_R"
ARM_IDS = (4, 5, 6, 7, 8, 9)
LEG_IDS = (10, 11, 12, 13, 14, 15)
LEGS = ("thigh_L", "shin_L", "thigh_R", "shin_R")
ARM_BONES = ("upperarm_L", "forearm_L", "upperarm_R", "forearm_R")
WAIT_S = 180.0  # generous: a loaded 2-core machine


class Swing:
    """hw_sim motion: servos ``ids`` swing (a slow sine, 25 degrees), the others hold 2048."""

    def __init__(self, ids, phase: float) -> None:
        self.ids, self.phase = set(ids), phase

    def position(self, joint: int, t: float) -> float:
        if joint not in self.ids:
            return 2048.0
        return 2048.0 + 285.0 * math.sin(2 * math.pi * 0.7 * t + self.phase + joint)


@pytest.fixture(scope="module")
def rig():
    return load_rig(BUILTIN_RIG)


class Live:
    """A ``puppet live`` subprocess whose stderr lines are collected as they come."""

    def __init__(self, port, *extra, rig_path=BUILTIN_RIG):
        self.proc = subprocess.Popen(["puppet", "live", "--rig", str(rig_path), "--port",
                                      str(port), "--watchdog-ms", "2000", *extra],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
        self.err: list[str] = []
        self._lines: queue.Queue = queue.Queue()
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self):
        for line in self.proc.stderr:
            self.err.append(line)
        self._lines.put(None)

    def finish(self, timeout_s: float = WAIT_S) -> tuple[int, str, str]:
        out = self.proc.stdout.read()
        code = self.proc.wait(timeout=timeout_s)
        self._lines.get(timeout=timeout_s)
        return code, out, "".join(self.err)


def _wait_for(condition, what: str, proc, timeout_s: float = WAIT_S):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return
        assert proc.poll() is None, f"live exited ({proc.returncode}) before {what}"
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _record_base(path, rig, seconds="3", rig_path=BUILTIN_RIG, motion=None):
    motion = Swing(LEG_IDS, 0.0) if motion is None else motion
    with hw_sim.serve(dict(rig.servo_map.models), motion=motion) as bus:
        code, out, err = Live(bus.port, "--seconds", seconds, "--record", str(path),
                              rig_path=rig_path).finish()
    assert code == 0, err
    return path


@pytest.fixture(scope="module")
def base(rig, tmp_path_factory):
    return _record_base(tmp_path_factory.mktemp("base") / "legs.mcap", rig)


def _export(take: Path) -> GLTF2:
    out = take.with_suffix(".glb")
    done = subprocess.run(["puppet", "export", str(take), "--gltf", str(out)],
                          capture_output=True, text=True, timeout=WAIT_S)
    assert done.returncode == 0, done.stderr
    return GLTF2().load(str(out)), done.stderr


def _rotations(gltf: GLTF2) -> dict[str, np.ndarray]:
    """{bone name: (N, 4) rotation keys (x, y, z, w)} of the first animation."""
    anim = gltf.animations[0]
    return {gltf.nodes[c.target.node].name: readers.accessor(gltf, anim.samplers[c.sampler].output)
            for c in anim.channels if c.target.path == "rotation"}


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    n = min(len(a), len(b))
    return np.degrees((Rotation.from_quat(a[:n]).inv() * Rotation.from_quat(b[:n])).magnitude())


def test_two_passes_export_legs_of_pass_1_arms_of_pass_2_and_free_bones_from_both(
        rig, base, tmp_path):
    layer = tmp_path / "arms.mcap"
    with hw_sim.serve(dict(rig.servo_map.models), motion=Swing(ARM_IDS, 1.5)) as bus:
        live = Live(bus.port, "--seconds", "3", "--over", str(base), "--joints", ARMS,
                    "--record", str(layer))
        _wait_for(lambda: bus.servo(LEG_IDS[0]).get("Torque Enable") == 1, "the base driven",
                  live.proc)
        assert all(bus.servo(i).get("Torque Enable") == 0 for i in ARM_IDS)  # in hand
        code, out, err = live.finish()
        assert code == 0, err
        assert "Traceback" not in err
        driven = sorted(set(int(i) for i in rig.servo_map.ids) - set(ARM_IDS))
        assert f"actuators {driven}: torque off (read back)" in err, err
        assert all(bus.servo(i).get("Torque Enable") == 0 for i in rig.servo_map.ids)
    with TakeReader(layer) as reader:
        assert reader.metadata.layer.servos == ARM_IDS
        assert reader.metadata.layer.base == base.name or Path(reader.metadata.layer.base) == base
        assert len(reader) > 100
    layered, said = _export(layer)
    legs, _ = _export(base)
    arms, _ = _export(raw_copy(layer, tmp_path / "arms_raw.mcap"))
    got, pass1, pass2 = _rotations(layered), _rotations(legs), _rotations(arms)
    for bone in LEGS:
        assert _angle_deg(got[bone], pass1[bone]).max() < 2.0, bone  # pass 1's legs
    for bone in ARM_BONES:
        assert _angle_deg(got[bone], pass2[bone]).max() < 0.5, bone  # pass 2's arms
        assert _angle_deg(got[bone], pass1[bone]).max() > 10.0, bone  # not pass 1's
    batch = tmp_path / "batch"
    done = subprocess.run(["puppet", "batch", str(layer), "--out", str(batch), "--formats",
                           "gltf"], capture_output=True, text=True, timeout=WAIT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    batched = _rotations(GLTF2().load(str(batch / "arms.glb")))
    for bone in LEGS + ARM_BONES:  # the batch composes the layer as export does
        assert _angle_deg(batched[bone], got[bone]).max() < 0.01, bone
    sensed = {s.joint for s in rig.servo_map.servos} | {"hips"}
    free = [b for b in got if b not in sensed]
    assert free
    # the free bones: solved from both passes (the legs of one, the arms of the other)
    assert max(_angle_deg(got[b], pass1[b]).max() for b in free) > 0.5


SOUND = SoundRef(sha256="ab" * 32, name="song.wav", path="/music/song.wav", offset_s=0.5,
                 rate=48000, channels=2, frames=96000)


def _short_base(path, rig) -> Path:
    """A 1 s base (legs swinging) performed to SOUND."""
    ids = np.asarray(rig.servo_map.ids)
    with TakeWriter(path, **take_header(rig), sound=SOUND) as w:
        from puppet.reading import Reading

        for r in range(101):
            ticks = np.array([Swing(LEG_IDS, 0.0).position(int(i), r / 100) for i in ids], np.int32)
            w.write(Reading(r * 10_000_000, ids, ticks, np.ones(len(ids), bool)))
    return path


@pytest.mark.parametrize("stop", ["SIGINT", "SIGTERM"])
def test_torque_is_read_back_off_when_a_layer_is_stopped(rig, tmp_path, stop):
    short = _short_base(tmp_path / "short.mcap", rig)
    layer = tmp_path / "layer.mcap"
    with hw_sim.serve(dict(rig.servo_map.models), motion=Swing(ARM_IDS, 0.5)) as bus:
        live = Live(bus.port, "--seconds", "600", "--over", str(short), "--servos", "4,5",
                    "--record", str(layer))
        _wait_for(lambda: bus.servo(10).get("Torque Enable") == 1, "the base driven", live.proc)
        _wait_for(lambda: "the base holds its last frame" in "".join(live.err),
                  "the base's end said", live.proc)
        live.proc.send_signal(getattr(signal, stop))
        code, out, err = live.finish()
        assert code == 0, err
        assert "Traceback" not in err
        assert "the base holds its last frame" in err, err
        assert "torque off (read back)" in err, err
        assert all(bus.servo(i).get("Torque Enable") == 0 for i in rig.servo_map.ids)
    with TakeReader(layer) as reader:
        assert reader.metadata.layer.servos == (4, 5) and len(reader) > 0
        assert reader.metadata.sound == SOUND  # the base's sound reference


def test_a_base_servo_that_drops_out_is_stopped_named_and_the_recording_goes_on(rig, tmp_path,
                                                                              base):
    layer = tmp_path / "layer.mcap"
    with hw_sim.serve(dict(rig.servo_map.models), motion=Swing(ARM_IDS, 0.5)) as bus:
        live = Live(bus.port, "--seconds", "600", "--over", str(base), "--joints", ARMS,
                    "--record", str(layer))
        try:
            _wait_for(lambda: bus.servo(12).get("Torque Enable") == 1, "the base driven",
                      live.proc)
            bus.inject("power_cycle", 12, duration_s=0.3)
            _wait_for(lambda: bus.servo(12).get("Torque Enable") == 0
                      and bus.servo(12).get("Bus Watchdog") == 0, "servo 12 back, off",
                      live.proc)
            size = layer.stat().st_size
            _wait_for(lambda: layer.stat().st_size > size + 20_000, "the recording going on",
                      live.proc)
            assert bus.servo(13).get("Torque Enable") == 1  # the others drive on
        finally:
            live.proc.send_signal(signal.SIGTERM)
            code, out, err = live.finish()
        assert code == 0, err
        assert "actuator_stopped" in out + err, out + err
        assert bus.servo(12).get("Torque Enable") == 0
        assert all(bus.servo(i).get("Torque Enable") == 0 for i in rig.servo_map.ids)


def test_a_rig_that_cannot_drive_plays_the_base_on_screen_only_said_once(tmp_path):
    ax = load_rig(BUILTIN_AX_RIG)
    base = _record_base(tmp_path / "ax.mcap", ax, seconds="1", rig_path=BUILTIN_AX_RIG,
                        motion="hold")
    layer = tmp_path / "layer.mcap"
    with hw_sim.serve(dict(ax.servo_map.models)) as bus:
        code, out, err = Live(bus.port, "--seconds", "2", "--over", str(base), "--joints", ARMS,
                              "--record", str(layer), rig_path=BUILTIN_AX_RIG).finish()
        assert code == 0, err
        assert err.count("the base plays on screen only") == 1, err
        assert "torque off (read back)" not in err  # nothing was driven
        assert all(bus.servo(i).get("Torque Enable") == 0 for i in ax.servo_map.ids)
    with TakeReader(layer) as reader:
        assert reader.metadata.layer.servos == ARM_IDS and len(reader) > 0


def _refused(*extra, rig_path=BUILTIN_RIG) -> str:
    done = subprocess.run(["puppet", "live", "--rig", str(rig_path), "--port", "/dev/null",
                           *extra], capture_output=True, text=True, timeout=WAIT_S)
    assert done.returncode != 0
    assert "Traceback" not in done.stderr
    return done.stderr


def test_a_layer_over_a_base_of_another_rig_is_refused_naming_both(rig, tmp_path):
    other = tmp_path / "dragon.mcap"
    header = take_header(rig)
    header["rig_name"] = "dragon"
    with TakeWriter(other, **header) as w:
        from puppet.reading import Reading

        ids = np.asarray(header["ids"])
        w.write(Reading(1, ids, np.full(len(ids), 2048, np.int32), np.ones(len(ids), bool)))
    err = _refused("--over", str(other), "--joints", "head", "--record",
                   str(tmp_path / "l.mcap"))
    assert "Error:" in err and "'critter'" in err and "'dragon'" in err, err
    assert not (tmp_path / "l.mcap").exists()


def test_a_layer_with_nothing_left_to_perform_and_unknown_joints_are_refused(tmp_path, rig):
    tail = BUILTIN_RIG.parent / "critter_tail.toml"
    base = tmp_path / "b.mcap"
    base.write_bytes(b"")
    err = _refused("--over", str(base), "--servos", "16", rig_path=tail)
    assert "Error:" in err and "nothing left to perform" in err, err
    err = _refused("--over", str(base), "--joints", "wing")
    assert "Error:" in err and "'wing'" in err, err
    err = _refused("--joints", "head")
    assert "--over" in err, err


def test_a_count_in_over_a_base_starts_the_base_at_the_layer_s_time_0(rig, base, tmp_path):
    layer = tmp_path / "arms.mcap"
    with hw_sim.serve(dict(rig.servo_map.models), motion=Swing(ARM_IDS, 1.5)) as bus:
        code, out, err = Live(bus.port, "--count-in", "1", "--seconds", "2.5", "--over",
                              str(base), "--joints", ARMS, "--record", str(layer)).finish()
        assert code == 0, err
        assert "Traceback" not in err
        assert all(bus.servo(i).get("Torque Enable") == 0 for i in rig.servo_map.ids)
    with TakeReader(layer) as reader:
        t, _, _ = reader.arrays()
        assert reader.metadata.layer.servos == ARM_IDS
        assert (t[-1] - t[0]) / 1e9 < 2.6  # from the count-in's end: the count-in not kept
    # the driven legs follow the base from the layer's time 0: not a count-in (1 s) late
    lag, rms, late = lag_s(base, layer, LEG_IDS[0], settle_s=0.3)
    assert abs(lag) < 0.2, (lag, rms, late)
    assert rms < 0.5 * late, (lag, rms, late)  # a clear fit: the servo follows the base
