"""The servo-units contract: joint angles round-trip through every ticks <-> radians conversion
the product uses (the rig's servo map, perform's take goals, live's actuator goals and limits,
the demo's motion), all of them ``puppet.servo_models.ServoUnits``, including the wrap cases:
whole turns of multi-turn ticks, a servo re-based by a reboot, gear != 1, sign -1, and a joint
whose limits span more than a turn (no wrap: the continuous count)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from puppet.demo import Performance
from puppet.drive.actuate import ActuatorGoals
from puppet.drive.actuators import ActuationPlan
from puppet.drive.goals import TakeGoals
from puppet.rig import builtin, load_rig
from puppet.rig.load import BUILTIN_RIG
from puppet.rig.servo_map import Servo, ServoMap
from puppet.servo_models import TICKS_PER_TURN, ServoUnits

X = np.array([1.0, 0.0, 0.0])
# id, model, sign, gear, zero ticks, limits (radians)
SERVOS = [Servo(1, "XL330-M288", "j", X, sign=1, gear=1.0, zero_ticks=2048, limits=(-np.pi, np.pi)),
          Servo(2, "XM430-W350", "j", X, sign=-1, gear=1.0, zero_ticks=1000, limits=(-1.0, 2.0)),
          Servo(3, "XM540-W270", "j", X, sign=1, gear=2.0, zero_ticks=-5000, limits=(-0.8, 0.8)),
          Servo(4, "XC330-T181", "j", X, sign=-1, gear=0.5, zero_ticks=3000, limits=(-2.5, 1.0)),
          Servo(5, "XL430-W250", "j", X, sign=1, gear=1.5, zero_ticks=100_000, limits=(-3.0, 3.0)),
          Servo(6, "XH430-W210", "j", X, sign=-1, gear=1.0, zero_ticks=2048,
                limits=(-1.5 * np.pi, 1.5 * np.pi))]  # spans 3π: no wrap
WRAPS = np.array([True, True, True, True, True, False])
JOINT_TURN_TICKS = np.array([TICKS_PER_TURN * s.gear for s in SERVOS])  # 4096, 4096, 8192, 2048...
HALF_TICK = np.pi / TICKS_PER_TURN * np.array([1 / s.gear for s in SERVOS])  # rounding, radians


FULL_TURN = np.array([s.limits[1] - s.limits[0] >= 2 * np.pi - 1e-12 for s in SERVOS])


def assert_angles(got, expected, atol: float) -> None:
    """got == expected within atol; a joint whose limits span exactly one turn reads its two
    ends (-π and π) as the one pose they are."""
    diff = np.asarray(got, float) - np.asarray(expected, float)
    full = np.broadcast_to(FULL_TURN[: diff.shape[-1]], diff.shape)
    diff = np.where(full, (diff + np.pi) % (2 * np.pi) - np.pi, diff)
    assert np.abs(diff).max() <= atol + 1e-9, np.abs(diff).max()


@pytest.fixture
def angles():
    """(40, 6) joint radians inside each servo's limits, the limits themselves included."""
    rng = np.random.default_rng(24)
    lo = np.array([s.limits[0] for s in SERVOS])
    hi = np.array([s.limits[1] for s in SERVOS])
    out = lo + (hi - lo) * rng.random((40, len(SERVOS)))
    out[0], out[1] = lo, hi
    return out


def test_servo_map_round_trips_and_wraps_whole_turns(angles):
    sm = ServoMap(SERVOS)
    for row in angles:
        ticks = sm.ticks_for(row)
        assert_angles(sm.angles(ticks), row, HALF_TICK.max())
        # A whole joint turn more or less on the count: the same angle where the joint wraps,
        # the continuous count (then clamped) where its limits span more than a turn.
        for turns in (-2, 1, 3):
            moved = (ticks + turns * JOINT_TURN_TICKS).astype(np.int32)
            got = sm.angles(moved)
            assert_angles(got[WRAPS], row[WRAPS], HALF_TICK.max())
            assert got[~WRAPS][0] == pytest.approx(
                np.clip(row[5] + SERVOS[5].sign * 2 * np.pi * turns, *SERVOS[5].limits), abs=1e-3)
    # A reboot re-bases a direct-drive servo into 0..4095: it still reads its angle.
    ticks = sm.ticks_for(angles[7])
    rebased = ticks.copy()
    rebased[:2] = np.mod(ticks[:2], TICKS_PER_TURN)
    assert_angles(sm.angles(rebased)[:2], angles[7][:2], HALF_TICK[0])


def test_the_per_frame_conversion_allocates_nothing():
    import tracemalloc

    sm = ServoMap(SERVOS)
    ticks = sm.ticks_for(np.zeros(len(SERVOS)))
    out = np.empty(len(SERVOS))
    sm.angles(ticks, out)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    for _ in range(100):
        sm.angles(ticks, out)
    grown = sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(before, "filename")
                if s.size_diff > 0 and "servo_models" in str(s.traceback))
    tracemalloc.stop()
    assert grown == 0


def test_perform_goals_carry_the_joint_angle_between_calibrations(angles):
    # Recorded on one puppet (zero ticks of the take), performed on another (the rig's), some
    # servos a whole turn away in the recording (a reboot mid-take): the goals hold the angles.
    take_zero = {s.id: s.zero_ticks + 37 * s.id - 900 for s in SERVOS}
    recorded = ServoMap([replace(s, zero_ticks=take_zero[s.id]) for s in SERVOS])
    ticks = np.array([recorded.ticks_for(row) for row in angles], np.int32)
    ticks[20:, :5] += (JOINT_TURN_TICKS[:5] * np.array([1, -1, 2, 1, -1])).astype(np.int32)
    rig = ServoMap(SERVOS)
    goals = TakeGoals(SERVOS, np.arange(len(angles)) / 100.0, ticks, np.ones(ticks.shape, bool),
                      take_zero, rig.zero)
    expected = angles.copy()
    expected[20:, 5] = angles[20:, 5]  # no turns were added to the servo that does not wrap
    played = np.array([rig.angles(np.rint(g).astype(np.int32)) for g in goals.goals])
    assert_angles(played, expected, 2 * HALF_TICK.max())
    lo, hi = goals.lo, goals.hi  # the goal limits are the joint limits, in the rig's ticks
    units = ServoUnits.for_servos(SERVOS, rig.zero)
    signs = np.array([s.sign for s in SERVOS])
    ends = units.angles(np.stack([lo, hi]), clamp=False)
    ends = np.where(signs > 0, ends, ends[::-1])  # a sign -1 servo's low tick is its high angle
    assert_angles(ends, [[s.limits[0] for s in SERVOS], [s.limits[1] for s in SERVOS]], 0.0)
    one_degree = units.ticks(np.radians(np.ones(len(SERVOS)))) - rig.zero
    np.testing.assert_allclose(goals.degrees(one_degree), 1.0)


def _rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis / np.linalg.norm(axis)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


@pytest.mark.parametrize("sign, gear, zero", [(1, 1.0, 2048), (-1, 1.0, 100), (1, 2.0, -3000),
                                              (-1, 0.5, 70_000), (1, 1.5, 5000)])
def test_live_actuator_goals_and_limits_round_trip(sign, gear, zero):
    rig = load_rig(BUILTIN_RIG.parent / "critter_tail.toml")
    tail = replace(rig.servo_map.actuators[0], sign=sign, gear=gear, zero_ticks=zero)
    skeleton = rig.skeleton
    bone = skeleton.index(tail.joint)
    axis = skeleton.frames[bone] @ np.asarray(tail.axis, float)
    sensor = ServoMap([tail])
    goals = ActuatorGoals([tail], skeleton, [zero])
    m = len(skeleton.names)
    for angle in np.linspace(*tail.limits, 9):
        T = np.zeros((4 * m, 3), np.float32)
        for j in range(m):
            T[4 * j:4 * j + 3] = np.eye(3)
        parent = skeleton.parents[bone]
        base = np.eye(3) if parent < 0 else _rotation_about(np.array([0.0, 0.0, 1.0]), 0.3)
        if parent >= 0:
            T[4 * parent:4 * parent + 3] = base.T
        T[4 * bone:4 * bone + 3] = (base @ _rotation_about(axis, angle)).T
        ticks = goals.goals(T)
        assert sensor.angles(np.array([round(float(ticks[0]))], np.int32))[0] == pytest.approx(
            angle, abs=1e-5 + HALF_TICK.max())
    tail_rig = replace(rig, servo_map=ServoMap([*rig.servo_map.servos[:-1], tail]))
    plan = ActuationPlan.for_rig(tail_rig, 100.0, max_speed_deg_s=90.0)
    units = ServoUnits.for_servos([tail], np.array([zero]))
    ends = np.sort(units.angles(np.array([plan.lo, plan.hi]), clamp=False), axis=0)[:, 0]
    np.testing.assert_allclose(ends, tail.limits, atol=1e-9)
    # 90 deg/s at 100 Hz: 0.9 joint degrees a cycle, in servo ticks (gear turns per joint turn)
    assert plan.max_step[0] == pytest.approx(0.9 * TICKS_PER_TURN / 360.0 * gear)


def test_the_demo_motion_is_the_angles_it_means():
    rig = builtin()
    motion = Performance(rig)
    sm = rig.servo_map
    for t in (0.0, 0.37, 1.1, 2.0):
        ticks = np.array([round(motion.position(int(i), t)) for i in sm.ids], np.int32)
        expected = []
        for k, s in enumerate(sm.servos):
            amplitude = min(0.7 * min(abs(s.limits[0]), abs(s.limits[1])), 0.9)
            phase = (math.pi if s.joint.endswith("_R") else 0.0) + 0.6 * k
            expected.append(amplitude * math.sin(2 * math.pi * t / motion.period_s + phase))
        np.testing.assert_allclose(sm.angles(ticks), expected, atol=HALF_TICK.max())
