"""An actuated tail in ``puppet live`` on hw_sim with the real SDK: the tail servo follows the
angle the solve gives the tail; torque is off after the command ends and after SIGTERM."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
import time

import numpy as np
import pytest

import hw_sim
from puppet.rig.load import BUILTIN_RIG
from puppet.reading import Reading
from puppet.drive.actuate import ActuatorGoals
from puppet.loop import Pipeline
from puppet.rig import load_rig

TAIL_RIG = BUILTIN_RIG.parent / "critter_tail.toml"
TAIL = 16
POSE_DEG = {10: 63.0, 11: -32.0, 12: -63.0, 13: 63.0, 14: 32.0, 15: -63.0}
"""Sensor angles (degrees, by servo id) of a pose that swings the legs: it moves the tail."""
BOUND_DEG = 3.0
"""How near the tail servo comes to the solved tail angle (solve tolerance + servo deadband)."""
WAIT_S = 120.0  # generous: a loaded 2-core machine


@pytest.fixture(scope="module")
def tail_rig():
    return load_rig(TAIL_RIG)


def _pose_ticks(rig) -> dict[int, int]:
    angles = np.array([np.radians(POSE_DEG.get(int(s.id), 0.0)) for s in rig.servo_map.servos])
    ticks = rig.servo_map.ticks_for(angles)
    return {int(i): int(t) for i, t in zip(rig.servo_map.ids, ticks) if int(i) != TAIL}


def _solved_tail(rig, pose: dict[int, int]) -> tuple[float, float]:
    """(angle rad, goal ticks) the solve gives the tail with the sensors at ``pose`` ticks."""
    sm = rig.servo_map
    ticks = np.array([pose.get(int(i), 2048) for i in sm.ids], np.int32)
    goals = ActuatorGoals(sm.actuators, rig.skeleton, sm.zero[sm.actuator_index])
    with Pipeline(rig, render=False) as pipeline:
        for _ in range(30):
            pipeline.solve(Reading(time.monotonic_ns(), sm.ids, ticks, np.ones(len(sm.ids), bool)))
        ticks_goal = float(goals.goals(pipeline.T)[0])
        return float(goals.angles[0]), ticks_goal


@pytest.fixture(scope="module")
def expected_tail(tail_rig):
    """(angle rad, goal ticks) the solve gives the tail in the pose (solved to convergence)."""
    return _solved_tail(tail_rig, _pose_ticks(tail_rig))


class Live:
    """A ``puppet live`` subprocess (in a process group of its own: the loop and its reader)
    whose stderr lines are collected as they come. ``started``: those of the running test
    (``_no_live_left`` kills what is left of each group when it ends)."""

    started: list[Live] = []

    def __init__(self, port, *extra, watchdog_ms: str = "2000"):
        Live.started.append(self)
        self.proc = subprocess.Popen(["puppet", "live", "--rig", str(TAIL_RIG), "--port", str(port),
                                      "--watchdog-ms", watchdog_ms, *extra],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
        self.err: list[str] = []
        self._lines: queue.Queue = queue.Queue()
        self._out: queue.Queue = queue.Queue()
        threading.Thread(target=self._pump, daemon=True).start()
        threading.Thread(target=lambda: self._out.put(self.proc.stdout.read()), daemon=True).start()

    def kill_group(self) -> None:
        """SIGKILL whatever is left of live's process group (its reader too)."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass

    def _pump(self):
        for line in self.proc.stderr:
            self._lines.put(line)
        self._lines.put(None)

    def finish(self, timeout_s: float = WAIT_S) -> tuple[int, str, str]:
        """(exit code, stdout, stderr) once live and every process of its group (its reader)
        let its output go; whatever of the group is left after that (or ``timeout_s``) is
        killed, so that no test leaves a process holding a port that the next pty reuses."""
        try:
            code = self.proc.wait(timeout=timeout_s)
            out = self._out.get(timeout=timeout_s)
            while (line := self._lines.get(timeout=timeout_s)) is not None:
                self.err.append(line)
        finally:
            self.kill_group()
        return code, out, "".join(self.err)


@pytest.fixture(autouse=True)
def _no_live_left():
    """A test that failed half-way leaves no live behind: one holding its port's lock would
    refuse the next test whose pseudo-terminal reuses the number (the lock is the device's)."""
    yield
    while Live.started:
        Live.started.pop().kill_group()


def _wait_for(condition, what: str, proc, timeout_s: float = WAIT_S):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        assert proc.poll() is None, f"live exited ({proc.returncode}) before {what}"
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_expected_tail_angle_is_a_real_motion(expected_tail):
    angle, _ = expected_tail
    assert abs(np.degrees(angle)) > 4 * BOUND_DEG  # the check below could not pass at rest


def test_tail_follows_the_solve_and_sigterm_leaves_torque_off(tail_rig, expected_tail):
    _, goal_ticks = expected_tail
    bound_ticks = BOUND_DEG * 4096 / 360.0
    with hw_sim.serve(dict(tail_rig.servo_map.models)) as bus:
        bus.set_positions(_pose_ticks(tail_rig))
        tail = bus.servo(TAIL)
        live = Live(bus.port, "--seconds", "600")
        _wait_for(lambda: tail.get("Torque Enable") == 1, "torque on", live.proc)
        assert tail.get("Bus Watchdog") == 100  # 2000 ms in 20 ms units, set after torque on
        _wait_for(lambda: abs(tail.get("Present Position") - goal_ticks) <= bound_ticks,
                  f"the tail near {goal_ticks:.0f} ticks", live.proc)
        live.proc.send_signal(signal.SIGTERM)
        code, _, err = live.finish()
        assert code == 0, err
        assert "Traceback" not in err
        assert f"actuators [{TAIL}]: torque off (read back)" in err, err
        assert tail.get("Torque Enable") == 0
        assert tail.get("Bus Watchdog") == 0


def test_tail_torque_is_off_after_a_normal_end(tail_rig):
    with hw_sim.serve(dict(tail_rig.servo_map.models)) as bus:
        bus.set_positions(_pose_ticks(tail_rig))
        live = Live(bus.port, "--seconds", "2")
        code, _, err = live.finish()
        assert code == 0, err
        assert f"actuators [{TAIL}]: torque off (read back)" in err, err
        assert bus.servo(TAIL).get("Torque Enable") == 0
        assert bus.servo(TAIL).get("Bus Watchdog") == 0


def test_a_host_stall_trips_the_watchdog_and_the_tail_follows_the_solve_again(tail_rig,
                                                                            expected_tail):
    """SIGSTOP of live's loop and reader past the Bus Watchdog (100 ms): the tail's watchdog
    trips; after SIGCONT live reports it, re-arms it and the tail follows the solve again (the
    pose changed during the stall: it must move), never frozen with torque on."""
    _, goal_ticks = expected_tail
    sm = tail_rig.servo_map
    rest = {int(i): int(z) for i, z in zip(sm.ids, sm.zero) if int(i) != TAIL}
    _, rest_goal = _solved_tail(tail_rig, rest)
    bound_ticks = BOUND_DEG * 4096 / 360.0
    assert abs(rest_goal - goal_ticks) > 4 * bound_ticks  # a move the check below can see
    with hw_sim.serve(dict(sm.models)) as bus:
        bus.set_positions(_pose_ticks(tail_rig))
        tail = bus.servo(TAIL)
        live = Live(bus.port, "--seconds", "600", watchdog_ms="100")
        try:
            _wait_for(lambda: abs(tail.get("Present Position") - goal_ticks) <= bound_ticks,
                      f"the tail near {goal_ticks:.0f} ticks", live.proc)
            os.killpg(live.proc.pid, signal.SIGSTOP)
            try:
                _wait_for(lambda: tail.get("Bus Watchdog") == -1, "the watchdog trip", live.proc)
                assert tail.get("Torque Enable") == 1  # frozen: only live can bring it back
                bus.set_positions(rest)
            finally:
                os.killpg(live.proc.pid, signal.SIGCONT)
            _wait_for(lambda: abs(tail.get("Present Position") - rest_goal) <= bound_ticks,
                      f"the tail following the solve again, near {rest_goal:.0f} ticks", live.proc)
            assert tail.get("Bus Watchdog") == 5  # re-armed: 100 ms in 20 ms units
            assert tail.get("Torque Enable") == 1
        finally:
            live.proc.send_signal(signal.SIGTERM)
            code, out, err = live.finish()
        assert code == 0, err
        assert "watchdog_tripped" in out, out  # in the summary's faults seen
        assert f"actuators [{TAIL}]: torque off (read back)" in err, err
        assert tail.get("Torque Enable") == 0


def test_a_short_adapter_drop_re_arms_the_tail_and_a_long_one_names_release(tail_rig,
                                                                          expected_tail):
    """An unplug of 0.5 s trips the tail's 100 ms watchdog: when the port is back the tail is
    re-armed and follows the solve again. An unplug that lasts to the end: live says torque is
    not confirmed off and names ``puppet release``."""
    _, goal_ticks = expected_tail
    sm = tail_rig.servo_map
    rest = {int(i): int(z) for i, z in zip(sm.ids, sm.zero) if int(i) != TAIL}
    _, rest_goal = _solved_tail(tail_rig, rest)
    bound_ticks = BOUND_DEG * 4096 / 360.0
    with hw_sim.serve(dict(sm.models)) as bus:
        bus.set_positions(_pose_ticks(tail_rig))
        tail = bus.servo(TAIL)
        live = Live(bus.link, "--seconds", "600", watchdog_ms="100")
        try:
            _wait_for(lambda: abs(tail.get("Present Position") - goal_ticks) <= bound_ticks,
                      f"the tail near {goal_ticks:.0f} ticks", live.proc)
            bus.set_positions(rest)
            bus.inject("unplug", duration_s=0.5)
            _wait_for(lambda: abs(tail.get("Present Position") - rest_goal) <= bound_ticks,
                      f"the tail following the solve again, near {rest_goal:.0f} ticks", live.proc)
            assert tail.get("Torque Enable") == 1
            bus.inject("unplug")
            _wait_for(lambda: tail.get("Bus Watchdog") == -1, "the watchdog trip", live.proc)
        finally:
            live.proc.send_signal(signal.SIGTERM)
            code, out, err = live.finish()
        assert code == 0, err
        assert "watchdog_tripped" in out, out
        assert f"warning: actuator servos [{TAIL}]: torque not confirmed off" in err, err
        assert f"`puppet release --port {bus.link}` turns it off" in err, err


def test_sigkill_of_live_has_its_reader_process_turn_the_tail_off(tail_rig, read_back):
    """SIGKILL of live's own process (the loop that computes the goals): the reader process,
    which holds the port, sees its parent gone and turns the actuator's torque off; read back
    through the client once it has let the port go."""
    models = dict(tail_rig.servo_map.models)
    with hw_sim.serve(models) as bus:
        bus.set_positions(_pose_ticks(tail_rig))
        tail = bus.servo(TAIL)
        live = Live(bus.port, "--seconds", "600")
        try:
            _wait_for(lambda: tail.get("Torque Enable") == 1, "torque on", live.proc)
            live.proc.kill()
            live.proc.wait(timeout=WAIT_S)
            assert read_back(bus.port, {TAIL: models[TAIL]}, timeout_s=WAIT_S) == {TAIL: 0}
            assert read_back(bus.port, {TAIL: models[TAIL]}, "bus_watchdog") == {TAIL: 0}
            _, _, err = live.finish()  # its stderr ends when the reader process has
            assert "Traceback" not in err, err
        finally:
            live.kill_group()
