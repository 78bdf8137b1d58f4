"""``perform`` on XL-320 servos (Protocol 2.0 with its own table: Goal Position 30, Moving
Speed 32, Control Mode 11, no Bus Watchdog) against hw_sim with the real SDK."""

from __future__ import annotations

import re

import numpy as np

import hw_sim
from puppet.drive import PerformOptions, perform
from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader


def test_an_xl320_rig_performs_in_joint_mode_and_ends_with_torque_off(tmp_path, make_take):
    text = BUILTIN_RIG.read_text().replace('mesh = "critter.npz"',
                                           f'mesh = "{BUILTIN_RIG.parent / "critter.npz"}"')
    text = re.sub(r'model = "[^"]*"', 'model = "XL-320"', text)
    text = re.sub(r"zero_ticks = \d+", "zero_ticks = 512", text)
    path = tmp_path / "critter_xl320.toml"
    path.write_text(text)
    rig = load_rig(path)
    ids = [int(i) for i in rig.servo_map.ids]
    t = np.arange(60) / 100.0
    take = make_take(tmp_path / "xl320.mcap", rig,
                     10.0 * np.sin(2 * np.pi * t[:, None] + np.arange(len(ids))[None, :]))
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        bus.servo(3).set("Control Mode", 1)           # one left in wheel mode
        report = perform(rig, TakeReader(take), bus.port,
                         PerformOptions(yes=True, latency_ms=20, watchdog=False))
        assert report.stop_reason == "end of take"
        assert report.tracking_median_deg < 10.0
        assert "servo 3: Control Mode 1 -> 2" in report.changes
        assert bus.servo(3).get("Control Mode") == 2
        assert report.torque_after == dict.fromkeys(ids, 0)
        assert {bus.servo(i).get("Torque Enable") for i in ids} == {0}
        assert all(0 < bus.servo(i).get("Goal Position") < 1023 for i in ids)
