"""``hw-sim --motion guided``: a person following ``puppet calibrate --guided``, one servo at a time
in the rig file's order, out in the joint's positive direction and back, starting when the host
first reads."""

from __future__ import annotations

import subprocess
import sys
import time

import dynamixel_sdk
import pytest

import hw_sim
from hw_sim.control_table import TICKS_PER_TURN
from hw_sim.motion import OneAtATime
from hw_sim.rig_servos import RigServo, read_rig_servos

RIG = """name = "three"
mesh = "three.glb"

[[servo]]
id = 4
model = "XL330-M288"
joint = "neck"
sign = -1
zero_ticks = 1000

[[servo]]
id = 2
model = "XL430-W250"
joint = "tail"
gear = 2.0
zero_ticks = 3000
limits_deg = [-90, 20]

[[servo]]
id = 9
model = "XM430-W350"
joint = "leg"
"""
TICKS_PER_DEG = TICKS_PER_TURN / 360.0
# id: (rest ticks, ticks away at full reach): 30° the way calibrate asks, sign and gear applied;
# servo 2's upper limit (20°) leaves less room than its lower one, so it turns 30° negative.
EXPECTED = {4: (1000, -30 * TICKS_PER_DEG), 2: (3000, -2.0 * 30 * TICKS_PER_DEG), 9: (2048, 30 * TICKS_PER_DEG)}


def _servos(tmp_path):
    (tmp_path / "three.toml").write_text(RIG)
    return read_rig_servos(tmp_path / "three.toml")


class Host:
    """A host reading every servo every 50 ms, as calibrate does (the motion sees each ask)."""

    def __init__(self, motion, t: float = 0.0) -> None:
        self.motion, self.t = motion, t

    def at(self, t: float) -> dict[int, float]:
        """Read until ``t`` s; the positions read at ``t``."""
        while self.t + 0.05 < t:
            self.t += 0.05
            for i in EXPECTED:
                self.motion.position(i, self.t)
        self.t = t
        return {i: self.motion.position(i, t) for i in EXPECTED}


def test_each_servo_in_turn_out_and_back_from_the_first_read(tmp_path):
    motion = OneAtATime(_servos(tmp_path), settle_s=5.0, ramp_s=0.4, hold_s=2.5, rest_s=1.2)
    rest = {i: float(r) for i, (r, _) in EXPECTED.items()}
    assert {i: motion.position(i, 0.0) for i in EXPECTED} == rest   # power-up is not the host asking
    start = 7.0                          # the host's first read, 7 s after start
    host = Host(motion, start)
    assert host.at(start) == rest
    assert host.at(start + 4.9) == rest  # settling: the host reads the rest pose
    for k, i in enumerate((4, 2, 9)):    # the file's order
        t0 = start + 5.0 + k * 4.5
        halfway = host.at(t0 + 0.2)      # ramping out
        assert abs(halfway[i] - (rest[i] + 0.5 * EXPECTED[i][1])) < 1e-6
        held = host.at(t0 + 0.4 + 1.0)
        assert held == pytest.approx({**rest, i: rest[i] + EXPECTED[i][1]}), (i, held)
        assert host.at(t0 + 3.3 + 0.6) == rest   # back, resting before the next servo
    assert host.at(start + 5.0 + 3 * 4.5 + 10.0) == rest   # all done: rest


def test_a_new_run_after_a_quiet_bus_gets_the_whole_sequence_again(tmp_path):
    motion = OneAtATime(_servos(tmp_path), settle_s=5.0, ramp_s=0.4, hold_s=2.5, rest_s=1.2, quiet_s=2.0)
    first = 3.0
    host = Host(motion, first)
    assert host.at(first + 6.5)[4] == pytest.approx(1000 + EXPECTED[4][1])   # a run that read until servo 4 was held
    again = first + 6.5 + 2.5            # 2.5 s quiet, then a second calibration run starts
    host = Host(motion, again)
    assert host.at(again)[4] == 1000.0
    assert host.at(again + 4.0)[4] == 1000.0                   # settling again
    assert host.at(again + 6.5)[4] == pytest.approx(1000 + EXPECTED[4][1])    # servo 4 first again


def test_servos_without_a_rig_go_in_id_order():
    motion = OneAtATime([RigServo(i, "XL330-M288") for i in (1, 3)], settle_s=1.0, ramp_s=0.1,
                        hold_s=1.0, rest_s=0.5)
    for t in (0.5, 1.0, 1.45):
        assert motion.position(1, t) == 2048 and motion.position(3, t) == 2048   # settling
    assert motion.position(1, 1.9) == pytest.approx(2048 + 30 * TICKS_PER_DEG)
    assert motion.position(3, 1.9) == 2048


def test_on_the_bus_one_servo_at_a_time_read_with_the_sdk(tmp_path, open_sdk):
    """The motion served to the real SDK: each servo leaves its rest alone, in the file's order.
    Read every 10 ms (as calibrate polls): each 1.5 s hold is seen many times over."""
    motion = OneAtATime(_servos(tmp_path), settle_s=1.0, ramp_s=0.2, hold_s=1.5, rest_s=0.5)
    with hw_sim.serve({s.id: s.model for s in _servos(tmp_path)}, motion=motion) as bus:
        sdk = open_sdk(bus.port)
        moved: list[int] = []
        deadline = time.monotonic() + 60
        while len(moved) < 3 or any(abs(_read(sdk, i) - EXPECTED[i][0]) > 2 for i in EXPECTED):
            assert time.monotonic() < deadline, moved
            ticks = {i: _read(sdk, i) for i in EXPECTED}
            away = [i for i, v in ticks.items() if abs(v - EXPECTED[i][0]) > 2]
            assert len(away) <= 1, ticks
            for i in away:
                assert (ticks[i] - EXPECTED[i][0]) * EXPECTED[i][1] > 0, ticks   # the side asked
                assert abs(ticks[i] - EXPECTED[i][0]) <= abs(EXPECTED[i][1]) + 1, ticks
                if not moved or moved[-1] != i:
                    moved.append(i)
            time.sleep(0.01)
    assert moved == [4, 2, 9]


def _read(sdk, dxl_id: int) -> int:
    """Present Position; a reply lost to a stall of this loaded machine is asked again."""
    for _ in range(50):
        value, result, error = sdk.packet.read4ByteTxRx(sdk.port, dxl_id, 132)
        if result != dynamixel_sdk.COMM_RX_TIMEOUT:
            break
    assert (result, error) == (0, 0), (dxl_id, result, error)
    return value - (1 << 32) if value >= 1 << 31 else value


def test_cli_names_the_motion_and_its_servos(tmp_path):
    (tmp_path / "three.toml").write_text(RIG)
    proc = subprocess.Popen([sys.executable, "-m", "hw_sim.cli", "--rig", str(tmp_path / "three.toml"),
                             "--motion", "guided"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().startswith("/dev/")
        assert "motion guided: servos 4, 2, 9 one at a time" in proc.stderr.readline()
    finally:
        proc.terminate()
        proc.wait(timeout=60)
    assert proc.returncode == 0


def test_pace_makes_the_person_quicker_and_is_refused_out_of_range_or_without_guided(tmp_path):
    quick = OneAtATime.at_pace(_servos(tmp_path), 2.0)
    assert (quick.settle_s, quick.ramp_s, quick.hold_s, quick.rest_s, quick.quiet_s) == (2.5, 0.2, 1.5, 0.6, 2.0)
    (tmp_path / "three.toml").write_text(RIG)
    rig = str(tmp_path / "three.toml")
    for args, said in ((["--motion", "guided", "--pace", "0"], "hw-sim: --pace 0.0: must be 0.1..4 "
                                                                "(1: the default person), got 0.0"),
                       (["--pace", "2"], "hw-sim: --pace is the pace of --motion guided")):
        result = subprocess.run([sys.executable, "-m", "hw_sim.cli", "--rig", rig, *args], capture_output=True,
                                text=True, timeout=60)
        assert result.returncode == 2 and said in result.stderr, result.stderr
        assert "Traceback" not in result.stderr and not result.stdout


def test_the_simulated_person_turns_the_way_calibrate_asks():
    """hw_sim's device-side copy of the rule (it imports nothing of puppet) agrees with
    calibrate's: positive, or negative where the limits leave more room that way; the turn stays
    inside the limits on that side."""
    from hw_sim.motion import GUIDED_TURN_DEG, guided_direction
    from puppet.rig.guided_calibration import TURN_DEG, turn_direction

    assert GUIDED_TURN_DEG == TURN_DEG
    cases = [(-90, 10), (-90, 20), (-5, 120), (-60, 60), (-20, 12), (-10, 12), (-180, 180), (10, 80),
             (-100, -10), (-30, 29.9), (-29.9, 29.9), (-45, 30)]
    for limits in cases:
        assert guided_direction(limits) == turn_direction(limits), limits
    examples = [(-90, 10), (-90, 20), (-5, 120), (-20, 12), (-10, 12)]
    assert [turn_direction(c) for c in examples] == [-1, -1, 1, -1, 1]
    servos = [RigServo(k + 1, "XL330-M288", 2048, 1, 1.0, (float(lo), float(hi)))
              for k, (lo, hi) in enumerate(cases)]
    motion = OneAtATime(servos, settle_s=0.0, ramp_s=0.1, hold_s=0.5, rest_s=0.1)
    motion.position(1, 1e-3)  # the host's first ask starts the sequence
    for k, s in enumerate(servos):
        held = (motion.position(s.id, k * motion.period_s + 0.3) - 2048) / TICKS_PER_DEG
        low, high = s.limits_deg
        assert held * turn_direction(s.limits_deg) > 0, s
        assert low <= held <= high, s
