"""``perform`` on a busy host (two processes spinning beside it on hw_sim with the real SDK):
a late reply costs a cycle, never the performance; a really silent servo still stops it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import hw_sim
from puppet.drive import DriveError, PerformOptions, perform
from puppet.drive.perform import READ_FAILURES_TO_STOP
from puppet.take import TakeReader

TAKES = 10
TAKE_S = 2.5  # a whole take under load each time; ten of them (about 2500 cycles)


@pytest.fixture
def busy_host():
    """Two processes spinning on the CPU for the test's duration."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


@pytest.fixture
def long_take(tmp_path, rig, make_take):
    t = np.arange(int(TAKE_S * 100)) / 100.0
    k = len(rig.servo_map.ids)
    angles = 15.0 * np.sin(2 * np.pi * 0.5 * t[:, None] + np.arange(k)[None, :])
    return make_take(tmp_path / "wave5.mcap", rig, angles)


def test_a_busy_host_costs_cycles_not_performances(rig, long_take, busy_host):
    """The user's options (only --yes): SDK deadline of a 1 ms adapter, 100 ms Bus Watchdog."""
    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        reasons = []
        for _ in range(TAKES):
            try:
                report = perform(rig, TakeReader(long_take), bus.port, PerformOptions(yes=True))
                reasons.append(report.stop_reason)
            except DriveError as err:
                reasons.append(str(err))
        assert reasons == ["end of take"] * TAKES
        assert {bus.servo(i).get("Torque Enable") for i in ids} == {0}
        # A servo that is really silent (longer than the tolerance) still stops it, named.
        with pytest.raises(DriveError) as info:
            perform(rig, TakeReader(long_take), bus.port, PerformOptions(yes=True),
                    on_phase=lambda p: p == "playback" and bus.inject("drop", ids=[4]))
        assert str(info.value).startswith(
            f"servo 4: no usable reading for {READ_FAILURES_TO_STOP} cycles, nor alone")
