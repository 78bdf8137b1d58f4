"""``puppet perform`` as a user runs it (subprocesses on hw_sim): Ctrl-C, SIGTERM and SIGKILL
(of its process: its guardian turns torque off; of every process at once: the Bus Watchdog
stops the servos and the next perform recovers); ``keys goto`` killed likewise; errors as
``Error:`` lines."""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import hw_sim

ARGS = ["--yes", "--latency-ms", "20", "--watchdog-ms", "2000"]


class Perform:
    """A ``puppet perform`` subprocess (``argv``: another command), in a process group of its
    own, whose stderr lines are collected as they come."""

    def __init__(self, take, port, *extra, argv=None):
        argv = argv or ["puppet", "perform", str(take), "--port", str(port), *ARGS, *extra]
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, start_new_session=True)
        self.lines: queue.Queue = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self):
        for line in self.proc.stderr:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def wait_line(self, text: str, timeout_s: float = 120.0) -> None:
        while True:
            line = self.lines.get(timeout=timeout_s)
            assert line is not None, f"exited before printing {text!r}: {self.seen}"
            self.seen.append(line)
            if text in line:
                return

    def finish(self, timeout_s: float = 120.0) -> tuple[int, str, str]:
        out = self.proc.stdout.read()
        code = self.proc.wait(timeout=timeout_s)
        while True:
            line = self.lines.get(timeout=timeout_s)
            if line is None:
                break
            self.seen.append(line)
        return code, out, "\n".join(self.seen)


def _torque(bus, ids):
    return {i: bus.servo(i).get("Torque Enable") for i in ids}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_with_torque_off(rig, wave_take, sig):
    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        run = Perform(wave_take, bus.port, "--loop")
        run.wait_line("phase: playback")
        assert set(_torque(bus, ids).values()) == {1}
        run.proc.send_signal(sig)
        code, out, err = run.finish()
        assert code == 0, err
        assert f"stopped: stopped by {sig.name}" in out
        assert "Traceback" not in err and "Warning" not in err  # its guardian's stderr too
        assert set(_torque(bus, ids).values()) == {0}
        assert {bus.servo(i).get("Bus Watchdog") for i in ids} == {0}


def _end_group(proc) -> None:
    """SIGKILL whatever is left of ``proc``'s process group (a test's leftovers)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


GUARDIAN_LINE = "ended without turning torque off (killed?): torque off (read back): servos "


def _guarded(run, bus, ids, models, read_back, who: str) -> None:
    """SIGKILL of ``run``'s own process (torque on): its guardian turns every servo's torque
    off and says so; read back through the client, Bus Watchdog cleared too."""
    killed = time.monotonic()
    run.proc.kill()
    try:
        run.wait_line(f"guardian: `puppet {who}` {GUARDIAN_LINE}")
        print(f"torque off said {time.monotonic() - killed:.3f} s after SIGKILL")  # -s shows it
        line = run.seen[-1]
        assert line.endswith(f"servos {ids}"), line  # none NOT confirmed
        assert read_back(bus.port, models) == dict.fromkeys(ids, 0)
        assert read_back(bus.port, models, "bus_watchdog") == dict.fromkeys(ids, 0)
    finally:
        _end_group(run.proc)
    assert "Traceback" not in "\n".join(run.seen)


def test_sigkill_of_perform_has_its_guardian_turn_torque_off(rig, wave_take, read_back):
    ids = [int(i) for i in rig.servo_map.ids]
    models = dict(rig.servo_map.models)
    with hw_sim.serve(models) as bus:
        run = Perform(wave_take, bus.port, "--loop")
        run.wait_line("phase: playback")
        assert set(_torque(bus, ids).values()) == {1}
        _guarded(run, bus, ids, models, read_back, "perform")


def test_sigkill_of_keys_goto_has_its_guardian_turn_torque_off(rig, tmp_path, read_back):
    """Killed during its countdown (torque on, goal = present): the same guardian."""
    from puppet.keys import write_shot
    from puppet.keys.example import critter_keys
    from puppet.rig.calibration import Calibration
    from puppet.rig.load import BUILTIN_RIG

    ids = [int(i) for i in rig.servo_map.ids]
    models = dict(rig.servo_map.models)
    shot = tmp_path / "shot.mcap"
    write_shot(shot, {"ids": ids, "models": models, "rig_map_text": "", "rig_name": rig.name,
                      "calibration_text": Calibration.capture(rig.servo_map.ids,
                                                              rig.servo_map.zero).to_record()},
               critter_keys(rig))
    puppet = str(Path(sys.executable).with_name("puppet"))
    with hw_sim.serve(models) as bus:
        run = Perform(shot, bus.port, argv=[puppet, "keys", "goto", str(shot), "2", "--rig",
                                            str(BUILTIN_RIG), "--port", bus.port, "--latency-ms",
                                            "20", "--watchdog-ms", "2000"])
        run.wait_line("3...")  # the countdown: torque is on
        assert set(_torque(bus, ids).values()) == {1}
        _guarded(run, bus, ids, models, read_back, "keys goto")


def test_sigkill_of_every_process_leaves_servos_to_their_watchdog_and_next_perform_recovers(
        rig, wave_take, wait_until):
    """The last line: perform and its guardian killed at once (the process group). A 500 ms
    watchdog: what trips it is the kill, not its period (a host stall that trips it before is
    re-armed); the next perform runs at the patient 2 s."""
    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        run = Perform(wave_take, bus.port, "--loop", "--watchdog-ms", "500")
        run.wait_line("phase: playback")
        os.killpg(run.proc.pid, signal.SIGKILL)
        run.finish()
        wait_until(lambda: all(bus.servo(i).get("Bus Watchdog") == -1 for i in ids),
                   what="every servo's Bus Watchdog to trip")
        assert all(bus.servo(i).get("Present Velocity") == 0 for i in ids)
        again = Perform(wave_take, bus.port, "--json")
        code, out, err = again.finish()
        assert code == 0, err
        for i in ids:
            assert f"servo {i}: Bus Watchdog -1 -> 0" in err
        report = json.loads(out)
        assert report["stop_reason"] == "end of take"
        assert sorted(report["recovered"]) == ids
        assert report["torque_after"] == {str(i): 0 for i in ids}
        assert set(_torque(bus, ids).values()) == {0}


def test_take_from_another_rig_is_an_error_line(rig, make_take, tmp_path):
    import numpy as np

    ids = [int(i) for i in rig.servo_map.ids][:-1]
    take = make_take(tmp_path / "other.mcap", rig, np.zeros((5, len(rig.servo_map.ids))),
                     ids=ids, models={i: rig.servo_map.models[i] for i in ids}, rig_name="other")
    result = subprocess.run(["puppet", "perform", str(take), "--port", "/dev/null", "--yes"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert "Error: " in result.stderr and "take from another rig" in result.stderr
    assert "Traceback" not in result.stderr


def test_missing_port_is_an_error_line(wave_take, tmp_path):
    result = subprocess.run(["puppet", "perform", str(wave_take), "--port",
                             str(tmp_path / "no-such-port"), "--yes"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert "Error: " in result.stderr and "no-such-port" in result.stderr
    assert "Traceback" not in result.stderr


TRIP = "Bus Watchdog tripped on "


def test_watchdog_trips_of_every_servo_are_one_line_per_condition(rig, wave_take):
    """perform stalled three times (SIGSTOP of its process past a 100 ms Bus Watchdog): each
    check finds all 15 servos tripped and re-arms them; that is said in one line naming them,
    repeats within NOTICE_REPEAT_S are counted and summed up at the stop, never a line per
    servo."""
    from puppet.drive.perform import NOTICE_REPEAT_S

    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        run = Perform(wave_take, bus.port, "--loop", "--watchdog-ms", "100")
        try:
            run.wait_line("phase: playback")
            started = time.monotonic()
            for _ in range(3):
                os.kill(run.proc.pid, signal.SIGSTOP)
                try:
                    _wait(lambda: all(bus.servo(i).get("Bus Watchdog") == -1 for i in ids),
                          "every watchdog tripped")
                finally:
                    os.kill(run.proc.pid, signal.SIGCONT)
                _wait(lambda: all(bus.servo(i).get("Bus Watchdog") == 5 for i in ids),
                      "every watchdog re-armed")
            elapsed = time.monotonic() - started
            run.proc.send_signal(signal.SIGINT)
            code, out, err = run.finish()
        finally:
            _end_group(run.proc)
    assert code == 0, err
    lines = [line for line in err.splitlines() if TRIP in line]
    print("\n".join(lines))  # -s shows them
    assert lines[0].startswith(f"{TRIP}servos {ids} "), lines
    assert not any(f"servo {i}: Bus Watchdog" in err for i in ids)
    said = [line for line in lines if not line.endswith("times in all")]
    assert len(said) <= 1 + elapsed // NOTICE_REPEAT_S, (elapsed, lines)
    if elapsed < NOTICE_REPEAT_S:  # every repeat came within the first line's period
        assert lines[-1].startswith(f"{TRIP}servos {ids} ") and lines[-1].endswith(" times in all")
        assert int(lines[-1].split(": ")[-1].split()[0]) >= 3, lines


def _wait(condition, what: str, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def test_notices_merge_repeats_and_sum_them_up(monkeypatch):
    import importlib

    performing = importlib.import_module("puppet.drive.perform")

    said: list[str] = []
    notices = performing._Notices(said.append)
    monkeypatch.setattr(performing, "NOTICE_REPEAT_S", 1e9)
    notices.add(performing.REARMED, [3, 1])
    notices.add(performing.REARMED, [2])
    notices.add(performing.STALLED, detail=" (0.2 s)")
    notices.add(performing.REARMED, [1])
    notices.close()
    assert said == [
        performing.REARMED.format(servos="servos [1, 3]"),
        "warning: the goal frames stalled (the host loop) (0.2 s)",
        performing.REARMED.format(servos="servos [1, 2, 3]") + ": 3 times in all"]
    said.clear()
    monkeypatch.setattr(performing, "NOTICE_REPEAT_S", 0.0)  # every time said, nothing left
    notices = performing._Notices(said.append)
    notices.add(performing.REARM_FAILED, [4], " (timeout)")
    notices.add(performing.REARM_FAILED, [4], " (timeout)")
    notices.close()
    assert said == [performing.REARM_FAILED.format(servos="servo 4") + " (timeout)"] * 2


def test_sigkill_during_setup_is_stopped_by_the_guardian_without_a_traceback(rig, wave_take,
                                                                           read_back):
    """Killed before torque went on (its guardian maybe still starting): the guardian stops
    the servos anyway (one may hold torque from an earlier run) and nothing prints a traceback."""
    ids = [int(i) for i in rig.servo_map.ids]
    models = dict(rig.servo_map.models)
    with hw_sim.serve(models) as bus:
        for i in ids:
            bus.servo(i).set("Torque Enable", 1)  # left on by an earlier run
        run = Perform(wave_take, bus.port, "--loop")
        run.wait_line("phase: setup")
        _guarded(run, bus, ids, models, read_back, "perform")


def test_perform_refuses_to_turn_torque_on_without_its_guardian(rig, wave_take, monkeypatch):
    """A guardian that cannot start (here: an interpreter that exits at once) is an error
    before the port opens: torque never goes on unguarded."""
    from puppet.drive import DriveError, PerformOptions, perform
    from puppet.take import TakeReader

    monkeypatch.setattr(sys, "executable", "/bin/false")
    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(DriveError) as info:
            perform(rig, TakeReader(wave_take), bus.port, PerformOptions(yes=True, latency_ms=20))
        assert set(_torque(bus, ids).values()) == {0}
    assert str(info.value).startswith("the torque guardian process ended before it was ready "
                                      "(exit status 1): torque stays off")
    assert info.value.report.torque_after == {}
