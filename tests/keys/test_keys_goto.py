"""``puppet keys goto`` on hw_sim with the real dynamixel_sdk: the servos ease to the stored key
(within 1° of it, read back from the simulated servos) and torque is off afterwards; a stop
signal during the move turns torque off too; a take without keys is refused before the port."""

import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

import hw_sim
from puppet.drive import PerformOptions, perform
from puppet.keys import write_shot
from puppet.keys.example import critter_keys
from puppet.rig import builtin
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader

PUPPET = Path(sys.executable).with_name("puppet")
PATIENT = ["--yes", "--latency-ms", "20", "--watchdog-ms", "2000"]


def make_shot(tmp_path, rig):
    from puppet.rig.calibration import Calibration

    shot = tmp_path / "shot.mcap"
    header = {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
              "rig_map_text": "", "rig_name": rig.name,
              "calibration_text": Calibration.capture(rig.servo_map.ids,
                                                      rig.servo_map.zero).to_record()}
    keys = critter_keys(rig)
    write_shot(shot, header, keys)
    return shot, keys


def positions(bus, rig):
    return np.array([bus.servo(int(i)).get("Present Position") for i in rig.servo_map.ids])


def torque(bus, rig):
    return {bus.servo(int(i)).get("Torque Enable") for i in rig.servo_map.ids}


def test_goto_reaches_the_key_and_turns_torque_off(tmp_path):
    """Positions are read once the move is over (the "playback" phase of the one-pose take:
    torque still on; hw_sim's shaft follows its motion source again once torque is off)."""
    rig = builtin()
    shot, keys = make_shot(tmp_path, rig)
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        there = []
        report = perform(rig, TakeReader(shot), bus.port,
                         PerformOptions(key=1, yes=True, latency_ms=20, watchdog_ms=2000.0),
                         on_phase=lambda p: there.append(positions(bus, rig)) if p == "playback" else None)
        assert report.stop_reason == "end of take"
        assert set(report.torque_after.values()) == {0} and torque(bus, rig) == {0}
        off_deg = rig.servo_map.units.joint_degrees(there[0] - keys.keys[1].ticks)
        assert np.abs(off_deg).max() <= 1.0, off_deg

        # the command: the same, said in words; the goals it left are the key's
        result = subprocess.run([str(PUPPET), "keys", "goto", str(shot), "2", "--rig",
                                 str(BUILTIN_RIG), "--port", bus.port, *PATIENT],
                                capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, result.stderr
        assert "key 2: reached; torque off on 15 of 15 servos" in result.stdout
        assert torque(bus, rig) == {0}
        goals = np.array([bus.servo(int(i)).get("Goal Position") for i in rig.servo_map.ids])
        assert np.abs(rig.servo_map.units.joint_degrees(goals - keys.keys[2].ticks)).max() <= 1.0


def test_a_stop_during_the_move_leaves_torque_off(tmp_path, wait_until):
    rig = builtin()
    shot, _ = make_shot(tmp_path, rig)
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        def interrupt(phase):
            if phase == "start":  # torque goes on now; Ctrl-C once it is on
                def later():
                    wait_until(lambda: 1 in torque(bus, rig), what="torque on")
                    signal.raise_signal(signal.SIGINT)
                threading.Thread(target=later, daemon=True).start()
        report = perform(rig, TakeReader(shot), bus.port,
                         PerformOptions(key=2, yes=True, latency_ms=20, watchdog_ms=2000.0),
                         on_phase=interrupt)
        assert report.stop_reason == "stopped by SIGINT"
        assert set(report.torque_after.values()) == {0}
        assert torque(bus, rig) == {0}


def test_goto_refuses_a_take_without_keys_and_a_missing_key(tmp_path):
    rig = builtin()
    shot, _ = make_shot(tmp_path, rig)
    gone = subprocess.run([str(PUPPET), "keys", "goto", str(shot), "9", "--port",
                           "/dev/puppet-no-such-port", *PATIENT],
                          capture_output=True, text=True, timeout=300)
    assert gone.returncode == 1 and "Traceback" not in gone.stderr
    assert f"{shot}: no key 9: the shot's keys are 0, 1, 2, 3" in gone.stderr


def test_performing_a_shot_follows_its_time_line(tmp_path):
    """perform's goals of a shot: the keys at their frames (40 frames apart at 24 fps: longer
    than a take's cut gaps), held after a "step" key."""
    from puppet.drive.goals import TakeGoals
    from puppet.keys import retime

    rig = builtin()
    shot, keys = make_shot(tmp_path, rig)
    keys = retime(keys, {1: 41, 2: 81, 3: 121})
    keys.keys[1].interpolation = "step"
    header_shot = tmp_path / "timed.mcap"
    from puppet.keys import read_shot

    header, _, _ = read_shot(shot)
    write_shot(header_shot, header, keys)
    goals = TakeGoals.from_take(TakeReader(header_shot), rig.servo_map)
    assert goals.duration_s == 120 / 24
    for f, k in ((0, 0), (40, 1), (60, 1), (79, 1), (80, 2), (120, 3)):
        np.testing.assert_allclose(goals.at(f / 24).copy(), keys.keys[k].ticks, atol=0.5)
