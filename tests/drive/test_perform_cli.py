"""``puppet perform`` as a user runs it (subprocesses on hw_sim): Ctrl-C, SIGTERM and SIGKILL,
then recovery by the next perform; errors as ``Error:`` lines."""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import threading

import pytest

import hw_sim

ARGS = ["--yes", "--latency-ms", "20", "--watchdog-ms", "2000"]


class Perform:
    """A ``puppet perform`` subprocess whose stderr lines are collected as they come."""

    def __init__(self, take, port, *extra):
        self.proc = subprocess.Popen(["puppet", "perform", str(take), "--port", str(port),
                                      *ARGS, *extra], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
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
        assert "Traceback" not in err
        assert set(_torque(bus, ids).values()) == {0}
        assert {bus.servo(i).get("Bus Watchdog") for i in ids} == {0}


def test_sigkill_leaves_servos_to_their_watchdog_and_next_perform_recovers(rig, wave_take, wait_until):
    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        run = Perform(wave_take, bus.port, "--loop")
        run.wait_line("phase: playback")
        run.proc.kill()
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
