"""puppet calibrate --guided against hw_sim: the test plays the user, moving one servo at a time
when asked; every id, sign, model and zero is found and written into the rig file, comments kept."""

import os
import queue
import signal
import subprocess
import threading
import time
import tomllib

import numpy as np
import pytest

import hw_sim
from puppet.rig import load_rig
from puppet.rig.guided_calibration import CONFIRM, HELD

# joint: (bus id, sign of a positive joint turn in ticks, axis); the rig file does not know them.
SECRET = {"hips": (21, 1, '"x"'), "tail base": (14, -1, '"z"'), "leg.L": (7, -1, '"x"'), "neck": (3, 1, '"-y"')}
MODELS = {21: "XL430-W250", 14: "XL330-M288", 7: "XM430-W350", 3: "XL330-M288", 9: "XL330-M288"}
#: Readings a scripted hand holds a joint: a move counts once held (CONFIRM + HELD readings).
HOLD = CONFIRM + HELD + 2
ZERO = {21: 1900, 14: 2300, 7: 2048, 3: 3950, 9: 1000}   # servo 3 passes 4095 when moved; 9 is not in the rig


def _rig_init(glb) -> None:
    """``puppet rig init GLB`` (in this process: rig init is not what these tests are about)."""
    from click.testing import CliRunner

    from puppet.cli import main

    result = CliRunner().invoke(main, ["rig", "init", str(glb)])
    assert result.exit_code == 0, result.output


def _rig(tmp_path, character):
    character.write_glb(tmp_path / "beast.glb")
    _rig_init(tmp_path / "beast.glb")
    rig = tmp_path / "beast.toml"
    text = character.enable_servos(rig.read_text(), {j: {"axis": axis} for j, (_, _, axis) in SECRET.items()})
    # a servo on the root: take it out of 'fixed', as the rig file says above its block
    text = text.replace('fixed = ["hips"]', 'fixed = []      ')
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
                                 "--timeout", "1"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith("Error: ")
    assert "servo #1 (hips)" in error and "no servo moved more than 13° of joint turn from its zero" in error
    assert rig.read_bytes() == before


def test_guided_calibration_needs_servo_blocks(tmp_path, character):
    character.write_glb(tmp_path / "beast.glb")
    _rig_init(tmp_path / "beast.glb")
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
        rows += [{**rest, servo: 2000 + sign * 300}] * HOLD + [rest] * 2
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
        rows += [{**rest, servo: rest[servo] + sign * 300}] * HOLD + [rest]
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
            session.run(read, read(), say=lambda text: None, threshold_deg=bad)
        assert info.value.field == "threshold_deg"
        assert info.value.message.startswith("must be a number 1..90 degrees, got ")
        assert read.k == 1  # only the rest reading given to run(); nothing more was read


# ---- never an unsure servo -------------------------------------------------------------------
READS = (0x02, 0x82, 0x8A, 0x92)   # READ, Sync Read, Fast Sync Read, Bulk Read


PATIENCE_S = 60.0  # as tests/conftest.py: a generous wait, never a threshold
PACE = 2.0
"""hw_sim's simulated person (``OneAtATime``) this many times as quick as its default: it rests
2.5 s from the first read, holds each joint 1.5 s. A move counts from three readings past the
threshold and the asks follow its timing (a joint already turned when asked is taken)."""


class _Hand:
    """The test's hand on the simulated puppet: it moves servos and holds them while the host
    reads (counted on the bus: no fixed sleeps)."""

    def __init__(self, bus, wait_until) -> None:
        self.bus, self.wait_until = bus, wait_until

    def reads(self) -> int:
        counts = self.bus.counts()
        return sum(counts.get(code, 0) for code in READS)

    def hold(self, readings: int) -> None:
        """Hold still until the host has read the bus ``readings`` more times."""
        start = self.reads()
        self.wait_until(lambda: self.reads() >= start + readings, what=f"{readings} host reads")

    def set(self, ticks: dict[int, int]) -> None:
        self.bus.set_positions(ticks)

    def rest(self) -> None:
        self.bus.set_positions(ZERO)

    def turn(self, servo: int, ticks: int) -> None:
        """Turn one servo ``ticks`` away from its rest, in steps, and leave it there."""
        for step in (0.1, 0.25, 0.45, 0.65, 1.0):
            self.bus.set_positions({servo: ZERO[servo] + round(step * ticks)})
            self.hold(1)


class _Calibrate:
    """``puppet calibrate --guided`` on ``port`` as a user runs it; its stderr lines, one by one."""

    def __init__(self, rig, port, *extra: str) -> None:
        self.proc = subprocess.Popen(["puppet", "calibrate", "--rig", str(rig), "--port", port, "--guided",
                                      "--yes", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.queue: queue.Queue = queue.Queue()
        self.log: list[str] = []
        threading.Thread(target=_lines, args=(self.proc.stderr, self.queue), daemon=True).start()

    def lines(self, patience_s: float = 240):
        deadline = time.monotonic() + patience_s
        while time.monotonic() < deadline:
            try:
                line = self.queue.get(timeout=1.0)
            except queue.Empty:
                continue
            if line is None:
                return
            self.log.append(line)
            yield line
        raise AssertionError("calibrate still asking after the test's patience:\n" + "".join(self.log))

    def finish(self) -> tuple[int, str]:
        stdout, _ = self.proc.communicate(timeout=PATIENCE_S)
        return self.proc.returncode, stdout


def test_unsure_moves_are_asked_again_with_the_reason(tmp_path, character, wait_until):
    """Two servos at once, a move too small to count, and the servo another block's id names
    are each answered with the reason and the same joint asked again; the sure move is taken."""
    rig = _rig(tmp_path, character)   # the blocks keep rig init's placeholder ids: leg.L's is 7
    doc = tomllib.loads(rig.read_text())
    assert {s["joint"]: s["id"] for s in doc["servo"]}["leg.L"] == 7

    def both(hand):   # hips and tail base turned together
        hand.set({21: ZERO[21] + 400, 14: ZERO[14] - 400})

    def small(hand):  # 100 ticks (8.8°) out and back: below the 13° threshold (148 ticks here)
        hand.set({21: ZERO[21] + 100})
        hand.hold(2 * (CONFIRM + HELD))
        hand.rest()

    def leg(hand):    # servo 7: the id leg.L's block names
        hand.turn(7, -400)

    unsure = {"hips": [both, small, leg]}
    with hw_sim.serve(MODELS) as bus:
        hand = _Hand(bus, wait_until)
        hand.rest()
        session = _Calibrate(rig, bus.port, "--timeout", "60")
        asks: list[str] = []
        for line in session.lines():
            if "direction" in line and line.startswith("["):
                joint = line.split("move '", 1)[1].split("'", 1)[0]
                attempt = asks.count(joint)
                asks.append(joint)
                if attempt < len(unsure.get(joint, [])):
                    unsure[joint][attempt](hand)
                else:
                    servo, sign, _ = SECRET[joint]
                    hand.turn(servo, sign * 400)
            elif "back to the rest pose" in line:
                hand.rest()
        code, stdout = session.finish()
    log = "".join(session.log)
    assert code == 0, log
    assert asks == ["hips"] * 4 + [n for n in character.NAMES if n in SECRET and n != "hips"]
    reasons = [line.split("asking again: ", 1)[1] for line in session.log if "not sure" in line]
    assert len(reasons) == 3, log
    assert reasons[0].startswith("servos 14 and 21 both moved more than 13°: move only 'hips'")
    assert reasons[1].startswith("servo 21 moved only 8.8° (100 ticks) and came back; a move counts from "
                                 "13° (148 ticks on it): move 'hips' farther")
    assert reasons[2].startswith("servo 7 is the id the rig file gives 'leg.L': move 'hips', or move "
                                 "servo 7 again if that id is wrong")
    assert "(ask 4 of 5)" in [line for line in session.log if line.startswith("[1/4]")][-1]
    doc = tomllib.loads(rig.read_text())
    got = {s["joint"]: (s["id"], s["sign"], s["zero_ticks"]) for s in doc["servo"]}
    assert got == {j: (i, sign, ZERO[i]) for j, (i, sign, _) in SECRET.items()}


def test_an_interrupted_session_writes_nothing(tmp_path, character, wait_until):
    """Ctrl-C after the first joint was found: no traceback, the rig file byte for byte as it
    was, no file left beside it."""
    rig = _rig(tmp_path, character)
    before, files = rig.read_bytes(), sorted(tmp_path.iterdir())
    with hw_sim.serve(MODELS) as bus:
        hand = _Hand(bus, wait_until)
        hand.rest()
        session = _Calibrate(rig, bus.port, "--timeout", "60")
        for line in session.lines():
            if line.startswith("[1/4] move 'hips'"):
                hand.turn(21, 400)
            elif "'hips': servo 21, sign +1" in line:
                hand.rest()
            elif line.startswith("[2/4]"):
                session.proc.send_signal(signal.SIGINT)
        code, stdout = session.finish()
    assert code == 1, "".join(session.log)
    assert "Traceback" not in "".join(session.log)
    assert rig.read_bytes() == before
    assert sorted(tmp_path.iterdir()) == files
    assert "rig file:" not in stdout


def test_a_joint_with_little_room_positive_is_asked_the_other_way_and_gets_its_own_servo(tmp_path, character):
    """The reported case: a joint with limits [-90, 10] cannot turn 13° positive. Driven by
    hw_sim's simulated person (``hw-sim --motion guided``): calibrate asks it to move negative,
    the side with room, and it gets its own servo and sign, not the next joint's."""
    from hw_sim.motion import OneAtATime
    from hw_sim.rig_servos import read_rig_servos

    truth = {"neck": (12, -1, 3000, "XL430-W250"), "tail base": (15, 1, 1000, "XL330-M288"),
             "leg.L": (17, -1, 2048, "XM430-W350")}
    axes = {"neck": '"x"', "tail base": '"z"', "leg.L": '"x"'}
    limits = {"neck": "[-90, 10]", "tail base": "[-60, 60]", "leg.L": "[-5, 120]"}
    rig = _rig_with(tmp_path, character, {j: {"axis": axes[j], "limits_deg": limits[j]} for j in truth})
    person = tmp_path / "person.toml"   # what the simulated puppet is: true ids, signs and zeros
    person.write_text("".join(f'[[servo]]\nid = {i}\nmodel = "{m}"\nsign = {s}\nzero_ticks = {z}\n'
                              f"limits_deg = {limits[j]}\n" for j, (i, s, z, m) in truth.items()))
    servos = read_rig_servos(person)
    # twice as quick as the default person (hw-sim --pace 2): calibrate takes a move from three
    # readings past the threshold, a quiet machine's 30 ms into the 1.5 s hold
    with hw_sim.serve({s.id: s.model for s in servos}, motion=OneAtATime.at_pace(servos, PACE)) as bus:
        session = _Calibrate(rig, bus.port, "--timeout", "60")
        prompts = [line for line in session.lines() if line.startswith("[")]
        code, stdout = session.finish()
    log = "".join(session.log)
    assert code == 0, log
    assert "not sure" not in log
    assert prompts[0].startswith("[1/3] move 'neck' in its negative direction (about x: swing its tip ")
    assert "its limits [-90.0, 10.0] leave more room that way" in prompts[0]
    assert prompts[1].startswith("[2/3] move 'tail base' in its positive direction")
    doc = tomllib.loads(rig.read_text())
    got = {s["joint"]: (s["id"], s["sign"], s["zero_ticks"], s["model"]) for s in doc["servo"]}
    assert got == truth, log
    loaded = load_rig(rig)   # the calibrated rig reads the person's turns with the right sign
    for servo in loaded.servo_map.servos:
        _, sign, zero, _ = truth[servo.joint]
        assert servo.sign == sign and servo.zero_ticks == zero


def _rig_with(tmp_path, character, servos):
    character.write_glb(tmp_path / "beast.glb")
    _rig_init(tmp_path / "beast.glb")
    rig = tmp_path / "beast.toml"
    text = character.enable_servos(rig.read_text(), servos)
    if "hips" in servos:  # a servo on the root: out of 'fixed', as the rig file says
        text = text.replace('fixed = ["hips"]', 'fixed = []      ')
    rig.write_text(text)
    return rig


def test_a_servo_turned_beyond_the_joints_limits_is_another_joints(tmp_path, character):
    """By the rig's geometry: hips may turn 40° positive (limits [-20, 40]); a servo turned 90° is
    not its servo. Asked again; the servo that fits is taken."""
    from puppet.rig.guided_calibration import GuidedCalibration

    rig = _rig_with(tmp_path, character, {"hips": {"axis": '"x"', "limits_deg": "[-20, 40]"},
                                          "neck": {"axis": '"x"'}})
    session = GuidedCalibration(rig)
    rest = {21: 2000, 3: 2000}
    rows = [rest] + [{**rest, 3: 2000 + 1024}] * HOLD + [rest] * 2      # 90° on servo 3
    rows += [{**rest, 21: 2000 - 400}] * HOLD + [rest] * 2              # 35° on servo 21: hips
    rows += [{**rest, 3: 2000 + 400}] * HOLD + [rest] * 2               # then neck
    read = _Script(list(rest), rows)
    said: list[str] = []
    found = session.run(read, read(), say=said.append, timeout_s=30)
    assert [(f.step.joint, f.id, f.sign) for f in found] == [("hips", 21, -1), ("neck", 3, 1)]
    reasons = [line for line in said if "not sure" in line]
    assert reasons == ["  not sure, asking again: servo 3 turned 90°, but 'hips' turns at most 40° that way "
                       "(limits_deg [-20.0, 40.0]): it is another joint's servo; move 'hips'; back to the "
                       "rest pose first"]


def test_the_id_another_block_names_is_taken_only_when_moved_again(tmp_path, character):
    """A file's id may be a placeholder (rig init writes 1, 2, ...): servo 7, named by leg.L's
    block, is refused for hips once, and taken when the same servo is moved again."""
    from puppet.rig.guided_calibration import GuidedCalibration

    rig = _rig_with(tmp_path, character, {"hips": {"axis": '"x"'}, "leg.L": {"axis": '"x"'}})
    session = GuidedCalibration(rig)
    rest = {7: 2000, 21: 2000}
    moved = [{**rest, 7: 2300}] * HOLD + [rest] * 2
    rows = [rest] + moved + moved + [{**rest, 21: 1700}] * HOLD + [rest] * 2
    read = _Script(list(rest), rows)
    said: list[str] = []
    found = session.run(read, read(), say=said.append, timeout_s=30)
    assert [(f.step.joint, f.id, f.sign) for f in found] == [("hips", 7, 1), ("leg.L", 21, -1)]
    assert sum("servo 7 is the id the rig file gives 'leg.L'" in line for line in said) == 1


def test_no_sure_move_in_every_ask_stops_naming_the_joint_and_writes_nothing(tmp_path, character):
    from puppet.rig.errors import RigError
    from puppet.rig.guided_calibration import TRIES, GuidedCalibration

    rig = _rig(tmp_path, character)
    before = rig.read_bytes()
    session = GuidedCalibration(rig)
    rest = {21: 2000, 14: 2000, 7: 2000, 3: 2000}
    rows = [rest] + ([{**rest, 21: 2400, 3: 1600}] * HOLD + [rest] * 2) * TRIES
    read = _Script(list(rest), rows)
    said: list[str] = []
    with pytest.raises(RigError) as info:
        session.run(read, read(), say=said.append, timeout_s=30)
    assert info.value.field == "servo #1 (hips)"
    assert info.value.message == (f"no sure move in {TRIES} asks (the last: servos 21 and 3 both moved more "
                                  "than 13°: move only 'hips'); nothing was written")
    assert sum(line.startswith("[1/4] move 'hips'") for line in said) == TRIES
    assert rig.read_bytes() == before


def test_a_joint_whose_limits_leave_no_room_for_a_move_is_refused_before_reading(tmp_path, character):
    from puppet.rig.errors import RigError
    from puppet.rig.guided_calibration import GuidedCalibration

    rig = _rig_with(tmp_path, character, {"hips": {"axis": '"x"', "limits_deg": "[-8, 6]"}})
    rest = {21: 2000}
    read = _Script(list(rest), [rest])
    with pytest.raises(RigError) as info:
        GuidedCalibration(rig).run(read, read(), say=lambda text: None)
    assert info.value.field == "servo #1 (hips) limits_deg"
    assert info.value.message.startswith("[-8.0, 6.0] leave the joint at most 8° of turn from the rest pose")
    assert "one counts from 13° of joint turn; widen the limits or lower --threshold" in \
        info.value.message
    assert read.k == 1


def test_lost_replies_neither_hide_a_move_nor_make_one(tmp_path, character):
    """Every other reading loses servo 21's reply (ok False, ticks 0): its move is still found
    from the good readings, and the lost ones are not read as a return to rest or a move."""
    from puppet.bus import Reading
    from puppet.rig.guided_calibration import GuidedCalibration

    rig = _rig_with(tmp_path, character, {"hips": {"axis": '"x"'}})
    session = GuidedCalibration(rig)
    rest = {21: 2000, 3: 2000}
    script = _Script(list(rest), [rest] + [{**rest, 21: 2300}] * (2 * HOLD) + [rest] * 4)

    def read():
        reading = script()
        if script.k % 2:
            ticks, ok = reading.ticks.copy(), reading.ok.copy()
            ticks[0], ok[0] = 0, False
            return Reading(reading.t_ns, reading.ids, ticks, ok)
        return reading

    said: list[str] = []
    found = session.run(read, script(), say=said.append, timeout_s=30)
    assert [(f.step.joint, f.id, f.sign) for f in found] == [("hips", 21, 1)]
    assert not any("not sure" in line for line in said)


def test_guided_calibration_on_an_ax_rig_against_hw_sim_guided_motion(tmp_path, character):
    """AX-12A servos (1024 positions over 300°: a 30° joint turn is 102 ticks, under the 150
    ticks an X-series threshold was): ``hw-sim --rig person.toml --motion guided`` turns each
    joint the way calibrate asks, and ``calibrate --guided`` finds every id, sign, zero and model
    with no unsure ask, the threshold converted by each servo's own ticks per turn (the person at
    ``--pace 2``, as in the test above)."""
    truth = {"neck": (12, -1, 400, "AX-12A"), "tail base": (15, 1, 620, "AX-12A"),
             "leg.L": (17, -1, 512, "AX-12A")}
    axes = {"neck": '"x"', "tail base": '"z"', "leg.L": '"x"'}
    limits = {"neck": "[-90, 10]", "tail base": "[-60, 60]", "leg.L": "[-5, 120]"}
    rig = _rig_with(tmp_path, character, {j: {"axis": axes[j], "limits_deg": limits[j],
                                              "model": '"AX-12A"'} for j in truth})
    person = tmp_path / "person.toml"   # what the simulated puppet is: true ids, signs and zeros
    person.write_text("".join(f'[[servo]]\nid = {i}\nmodel = "{m}"\nsign = {s}\nzero_ticks = {z}\n'
                              f"limits_deg = {limits[j]}\n" for j, (i, s, z, m) in truth.items()))
    sim = subprocess.Popen(["hw-sim", "--rig", str(person), "--motion", "guided", "--pace", str(PACE)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = sim.stdout.readline().strip()
        assert port.startswith("/dev/"), sim.stderr.read() if sim.poll() is not None else port
        session = _Calibrate(rig, port, "--timeout", "60")
        prompts = [line for line in session.lines() if line.startswith("[")]
        code, stdout = session.finish()
    finally:
        sim.send_signal(signal.SIGTERM)
        sim.wait(timeout=PATIENCE_S)
    log = "".join(session.log)
    assert code == 0, log
    assert "not sure" not in log
    assert [p.split("'")[1] for p in prompts] == list(truth)
    doc = tomllib.loads(rig.read_text())
    got = {s["joint"]: (s["id"], s["sign"], s["zero_ticks"], s["model"]) for s in doc["servo"]}
    assert got == truth, log
    loaded = load_rig(rig)   # the calibrated AX rig reads a 30° joint turn (inside its limits) as 30°
    turn = {"neck": -30.0, "tail base": 30.0, "leg.L": 30.0}
    servos = loaded.servo_map.servos
    ticks = np.array([truth[s.joint][2] + truth[s.joint][1] * round(turn[s.joint] * 1024 / 300)
                      for s in servos], np.int32)
    np.testing.assert_allclose(np.degrees(loaded.servo_map.angles(ticks)), [turn[s.joint] for s in servos],
                               atol=0.3)
