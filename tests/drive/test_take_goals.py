"""perform's goals at a cycle's time are the take's one rule's ticks there, converted to goal
ticks: interpolated the short way round, long gaps cut, flagged readings held."""

import numpy as np

from puppet.drive.goals import TakeGoals
from puppet.take import Playback


def test_goals_follow_the_takes_rule_at_any_time(rig):
    k = len(rig.servo_map)
    t = np.array([0, 50_000_000, 3_050_000_000, 3_100_000_000], np.int64)  # a 3 s gap: cut to 1 s
    zero = rig.servo_map.zero.astype(np.int64)
    ticks = np.stack([zero, zero + 40, zero - 60, zero + 2]).astype(np.int32)
    ok = np.ones((4, k), bool)
    ok[2, 0] = False  # servo 0 held at reading 1's ticks there
    ticks[2, 0] = ticks[1, 0]
    goals = TakeGoals(rig.servo_map.servos, t, ticks, ok, {}, rig.servo_map.zero)
    frames = Playback(t, ticks, ok, rig.servo_map.ids)
    assert goals.duration_s == frames.duration_s == 1.1
    for seconds in (0.0, 0.02, 0.05, 0.3, 0.55, 1.05, 1.1, 5.0):
        expected = frames.at(seconds).ticks  # same zero ticks: goal ticks are the take's ticks
        np.testing.assert_allclose(goals.at(seconds), expected, atol=1e-9)
    assert goals.at(0.55)[1] == float(zero[1] + 40 + round(0.5 * -100))  # half way across the cut gap
    np.testing.assert_allclose(goals.goals, ticks, atol=1e-9)
