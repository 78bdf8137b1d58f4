"""An actuated tail on a Protocol 1.0 bus in ``puppet live`` (hw_sim, the real SDK): an AX-12A
tail servo follows the angle the solve gives the tail; it is driven only with --no-watchdog
(AX has no Bus Watchdog) and its torque is off after SIGTERM, read back."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time

import numpy as np

import hw_sim
from puppet.drive.actuate import ActuatorGoals
from puppet.loop import Pipeline
from puppet.reading import Reading
from puppet.rig import load_rig

TAIL = 16
POSE_DEG = {10: 63.0, 11: -32.0, 12: -63.0, 13: 63.0, 14: 32.0, 15: -63.0}
"""Leg angles (degrees) of the MX-28 leg servos 10..15: a pose that swings the tail."""
BOUND_DEG = 3.0
WAIT_S = 120.0
TAIL_BLOCK = """
[[servo]]
id = 16
model = "AX-12A"
joint = "tail1"
axis = "x"
role = "actuator"
zero_ticks = 512
limits_deg = [-60, 60]
"""


def _wait_for(condition, what: str, proc, timeout_s: float = WAIT_S):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        assert proc.poll() is None, f"live exited ({proc.returncode}) before {what}"
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_an_ax_tail_follows_the_solve_and_sigterm_leaves_torque_off(protocol1_rig):
    path = protocol1_rig.with_name("critter_p1_tail.toml")
    path.write_text(protocol1_rig.read_text().split("[[pin]]")[0] + TAIL_BLOCK + "\n[[pin]]"
                    + protocol1_rig.read_text().split("[[pin]]", 1)[1])
    rig = load_rig(path)
    sm = rig.servo_map
    angles = np.array([np.radians(POSE_DEG.get(int(i), 0.0)) for i in sm.ids])
    pose = sm.ticks_for(angles)                       # each servo's own ticks (AX: ~512 at rest)
    goals = ActuatorGoals(sm.actuators, rig.skeleton, sm.zero[sm.actuator_index])
    with Pipeline(rig, render=False) as pipeline:
        for _ in range(30):
            pipeline.solve(Reading(0, sm.ids, pose, np.ones(len(sm.ids), bool)))
        goal = float(goals.goals(pipeline.T)[0])
    assert abs(np.degrees(goals.angles[0])) > 4 * BOUND_DEG   # a real motion of the tail
    bound = BOUND_DEG * 1228.8 / 360.0                        # AX ticks

    with hw_sim.serve(dict(sm.models)) as bus:
        # hw_sim's shafts count 4096 per turn from the middle (2048): the legs are MX-28 (their
        # ticks), the other sensors AX-12A left at rest.
        bus.set_positions({int(i): int(t) for i, t in zip(sm.ids, pose) if 10 <= int(i) <= 15})
        refused = subprocess.run(["puppet", "live", "--rig", str(path), "--port", bus.port,
                                  "--seconds", "1"], capture_output=True, text=True, timeout=WAIT_S)
        assert refused.returncode == 1
        assert "servo 16 model: model AX-12A has no Bus Watchdog" in refused.stderr
        tail = bus.servo(TAIL)
        assert tail.get("Torque Enable") == 0
        proc = subprocess.Popen(["puppet", "live", "--rig", str(path), "--port", bus.port,
                                 "--no-watchdog", "--seconds", "600"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, start_new_session=True)
        try:
            _wait_for(lambda: tail.get("Torque Enable") == 1, "torque on", proc)
            _wait_for(lambda: abs(tail.get("Present Position") - goal) <= bound,
                      f"the tail near {goal:.0f} ticks", proc)
            proc.send_signal(signal.SIGTERM)
            out, err = proc.communicate(timeout=WAIT_S)
        finally:  # nothing left holding the port (a pty reusing its number would be refused)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
        assert proc.returncode == 0, err
        assert "Traceback" not in err
        assert f"actuators [{TAIL}]: torque off (read back)" in err, err
        assert tail.get("Torque Enable") == 0
