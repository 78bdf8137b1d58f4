"""puppet calibrate --guided against hw_sim: the test plays the user, moving one servo at a time
when asked; every id, sign, model and zero is found and written into the rig file, comments kept."""

import os
import queue
import subprocess
import threading
import time
import tomllib

import numpy as np
import pytest

import hw_sim
from puppet.rig import load_rig

# joint: (bus id, sign of a positive joint turn in ticks, axis); the rig file does not know them.
SECRET = {"hips": (21, 1, '"x"'), "tail base": (14, -1, '"z"'), "leg.L": (7, -1, '"x"'), "neck": (3, 1, '"-y"')}
MODELS = {21: "XL430-W250", 14: "XL330-M288", 7: "XM430-W350", 3: "XL330-M288", 9: "XL330-M288"}
ZERO = {21: 1900, 14: 2300, 7: 2048, 3: 3950, 9: 1000}   # servo 3 passes 4095 when moved; 9 is not in the rig


def _rig(tmp_path, character):
    character.write_glb(tmp_path / "beast.glb")
    result = subprocess.run(["puppet", "rig", "init", tmp_path / "beast.glb"], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    rig = tmp_path / "beast.toml"
    text = character.enable_servos(rig.read_text(), {j: {"axis": axis} for j, (_, _, axis) in SECRET.items()})
    rig.write_text(text)
    return rig


def _lines(stream, out: queue.Queue):
    for line in stream:
        out.put(line)
    out.put(None)


def test_guided_calibration_finds_every_id_sign_and_zero(tmp_path, character):
    rig = _rig(tmp_path, character)
    before = rig.read_text()
    with hw_sim.serve(MODELS) as bus:
        bus.set_positions(ZERO)
        proc = subprocess.Popen(["puppet", "calibrate", "--rig", str(rig), "--port", bus.port, "--guided",
                                 "--yes", "--timeout", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=_lines, args=(proc.stderr, lines), daemon=True).start()
        prompts, log = [], []
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:
            try:
                line = lines.get(timeout=1.0)
            except queue.Empty:
                continue
            if line is None:
                break
            log.append(line)
            if "in its positive direction" in line:
                joint = line.split("move '", 1)[1].split("'", 1)[0]
                prompts.append(joint)
                servo, sign, _ = SECRET[joint]
                for step in (40, 100, 180, 260, 400):  # a hand moving the joint, one servo at a time
                    bus.set_positions({servo: ZERO[servo] + sign * step})
                    time.sleep(0.03)
            elif "back to the rest pose" in line:
                servo = SECRET[prompts[-1]][0]
                bus.set_positions({servo: ZERO[servo]})
        stdout, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, "".join(log)
    assert prompts == [n for n in character.NAMES if n in SECRET]  # in the file's order, each once
    doc = tomllib.loads(rig.read_text())
    got = {s["joint"]: (s["id"], s["sign"], s["zero_ticks"], s["model"]) for s in doc["servo"]}
    assert got == {j: (i, sign, ZERO[i], MODELS[i]) for j, (i, sign, _) in SECRET.items()}
    # Comments and layout kept: every line of the file before is still there, in order, except
    # the changed values (which keep their trailing comments).
    after = rig.read_text().splitlines()
    kept = [line for line in before.splitlines() if not line.split("=")[0].strip() in ("id", "model", "sign",
                                                                                          "zero_ticks")]
    assert [line for line in after if line in kept] == kept
    id_lines = [line for line in after if line.startswith("id = ")]
    assert len(id_lines) == 4 and all("# bus id" in line for line in id_lines)
    # The calibrated rig reads a positive joint turn as a positive angle.
    loaded = load_rig(rig)
    ticks = np.array([ZERO[s.id] + SECRET[s.joint][1] * 200 for s in loaded.servo_map.servos], np.int32)
    np.testing.assert_allclose(loaded.servo_map.angles(ticks), np.radians(200 * 360 / 4096), atol=1e-9)
    assert "neck (-y): servo 3, sign +1, zero 3950" in stdout


def test_guided_calibration_times_out_naming_the_joint_and_keeps_the_file(tmp_path, character):
    rig = _rig(tmp_path, character)
    before = rig.read_bytes()
    with hw_sim.serve(MODELS) as bus:
        bus.set_positions(ZERO)
        result = subprocess.run(["puppet", "calibrate", "--rig", rig, "--port", bus.port, "--guided", "--yes",
                                 "--timeout", "2"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith("Error: ")
    assert "servo #1 (hips)" in error and "no servo moved more than 150 ticks" in error
    assert rig.read_bytes() == before


def test_guided_calibration_needs_servo_blocks(tmp_path, character):
    character.write_glb(tmp_path / "beast.glb")
    subprocess.run(["puppet", "rig", "init", tmp_path / "beast.glb"], check=True, capture_output=True, timeout=120)
    result = subprocess.run(["puppet", "calibrate", "--rig", tmp_path / "beast.toml", "--port", "/dev/null-none",
                             "--guided", "--yes"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert "beast.toml: servo: no [[servo]] blocks" in result.stderr


class _Script:
    """Readings a hand would make, one per read() call: (ticks by id) rows, the last repeated."""

    def __init__(self, ids, rows):
        self.ids, self.rows, self.k = np.array(ids), rows, 0

    def __call__(self):
        from puppet.bus import Reading

        row = self.rows[min(self.k, len(self.rows) - 1)]
        self.k += 1
        return Reading(self.k, self.ids, np.array([row[i] for i in self.ids], np.int32), np.ones(len(self.ids), bool))


def test_one_stray_reading_is_not_a_move(tmp_path, character):
    from puppet.rig.guided_calibration import GuidedCalibration

    rig = _rig(tmp_path, character)
    session = GuidedCalibration(rig)
    rest = {21: 2000, 14: 2000, 7: 2000, 3: 2000}
    spike = {**rest, 7: 2900}  # one corrupt value on servo 7
    rows = [rest, spike, rest]
    for joint in [n for n in character.NAMES if n in SECRET]:
        servo, sign, _ = SECRET[joint]
        rows += [{**rest, servo: 2000 + sign * 300}] * 3 + [rest] * 2
    read = _Script(list(rest), rows)
    said = []
    found = session.run(read, read(), say=said.append, timeout_s=30)
    assert [(f.step.joint, f.id, f.sign, f.zero_ticks) for f in found] == [
        (j, SECRET[j][0], SECRET[j][1], 2000) for j in character.NAMES if j in SECRET]
    assert "about x: swing its tip down" in said[0]  # hips, in the character's words


def test_guided_write_keeps_a_named_calibration_file_in_step(tmp_path, character):
    """A rig naming a calibration file (which overrides zero_ticks) gets the new zeros there too."""
    from puppet.rig import Calibration
    from puppet.rig.guided_calibration import GuidedCalibration

    rig = _rig(tmp_path, character)
    rig.write_text(rig.read_text().replace('mesh = "beast.glb"\n',
                                           'mesh = "beast.glb"\ncalibration = "beast.calibration.toml"\n'))
    Calibration({21: 1, 99: 1234}).save(tmp_path / "beast.calibration.toml")
    session = GuidedCalibration(rig)
    rest = {21: 2010, 14: 2020, 7: 2030, 3: 2040}
    rows = [rest]
    for joint in [n for n in character.NAMES if n in SECRET]:
        servo, sign, _ = SECRET[joint]
        rows += [{**rest, servo: rest[servo] + sign * 300}] * 3 + [rest]
    read = _Script(list(rest), rows)
    found = session.run(read, read(), say=lambda text: None, models=MODELS, timeout_s=30)
    assert session.write(found) == rig
    assert session.calibration_file == tmp_path / "beast.calibration.toml"
    assert Calibration.load(session.calibration_file).zero_ticks == {**rest, 99: 1234}
    loaded = load_rig(rig)
    assert dict(zip(loaded.servo_map.ids.tolist(), loaded.servo_map.zero.tolist())) == rest


def test_a_threshold_of_zero_or_below_is_refused_before_any_reading(tmp_path, character):
    """0 would take a servo that did not move for the one that did (ids and signs swapped);
    a negative one never ends. Refused naming the value and the range, nothing read."""
    from puppet.rig.errors import RigError
    from puppet.rig.guided_calibration import GuidedCalibration

    session = GuidedCalibration(_rig(tmp_path, character))
    rest = {21: 2000, 14: 2000, 7: 2000, 3: 2000}
    for bad in (0, -5, 1e9, float("nan")):
        read = _Script(list(rest), [rest])
        with pytest.raises(RigError) as info:
            session.run(read, read(), say=lambda text: None, threshold_ticks=bad)
        assert info.value.field == "threshold_ticks"
        assert info.value.message.startswith("must be an integer 8..2048 ticks, got ")
        assert read.k == 1  # only the rest reading given to run(); nothing more was read
