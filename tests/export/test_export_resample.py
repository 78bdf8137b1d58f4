"""Resampling readings to a frame rate: counts, times, interpolation, wraps, determinism."""

import numpy as np
import pytest

from puppet.export import ExportError, Resampler, frame_offsets_ns
from puppet.export.resample import check_fps

IDS = np.array([1, 2])


def test_frame_counts_for_the_usual_rates():
    duration = 3_000_000_000  # 3 s
    for fps, frames in ((24, 73), (25, 76), (30, 91), (50, 151), (60, 181), (7.5, 23)):
        offsets = frame_offsets_ns(duration, fps)
        assert len(offsets) == frames
        assert offsets[0] == 0
        np.testing.assert_array_equal(offsets, np.rint(np.arange(frames) * 1e9 / fps))
    assert len(frame_offsets_ns(999_999_999, 24)) == 24  # 23/24 s < 0.999... < 24/24 s
    assert len(frame_offsets_ns(0, 24)) == 1


def test_ticks_are_interpolated_between_irregular_readings():
    t = np.array([0, 10_000_000, 40_000_000, 50_000_000], np.int64)  # 0, 10, 40, 50 ms
    ticks = np.array([[100, 0], [200, 10], [500, 40], [600, 50]], np.int32)
    ok = np.ones((4, 2), bool)
    frames = Resampler(t, ticks, ok, IDS, fps=50)  # every 20 ms: 0, 20, 40 ms
    assert len(frames) == 3
    got = [r.ticks.tolist() for r in frames]
    assert got == [[100, 0], [300, 20], [500, 40]]
    assert [r.t_ns for r in frames] == [0, 20_000_000, 40_000_000]


def test_interpolation_takes_the_short_way_round_a_wrap():
    t = np.array([0, 10_000_000], np.int64)
    ticks = np.array([[4090, 10], [4, 4090]], np.int32)  # servo 1 wraps up, servo 2 down
    frames = Resampler(t, ticks, np.ones((2, 2), bool), IDS, fps=200)  # 0, 5, 10 ms
    middle = list(frames)[1].ticks
    assert middle.tolist() == [4090 + 5, 10 - 8]  # +10 and -16 ticks, halved; never half a turn


def test_a_failed_servo_flags_the_frames_it_touches():
    t = np.array([0, 10_000_000, 20_000_000], np.int64)
    ticks = np.zeros((3, 2), np.int32)
    ok = np.array([[True, True], [True, False], [True, True]])
    frames = list(Resampler(t, ticks, ok, IDS, fps=400))  # every 2.5 ms
    flagged = [not r.ok[1] for r in frames]
    assert flagged[0] is False and flagged[4] is True and flagged[8] is False
    assert all(flagged[1:8])


def test_same_input_gives_the_same_frames():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.integers(1_000_000, 9_000_000, 200)).astype(np.int64)
    ticks = rng.integers(-5000, 5000, (200, 2)).astype(np.int32)
    ok = np.ones((200, 2), bool)
    a = [r.ticks.tobytes() for r in Resampler(t, ticks, ok, IDS, fps=24)]
    b = [r.ticks.tobytes() for r in Resampler(t, ticks.copy(), ok, IDS, fps=24.0)]
    assert a == b


def test_bad_rates_and_times_are_refused():
    for bad in (0, -24, float("nan"), float("inf"), "abc"):
        with pytest.raises(ExportError, match="frames per second must be"):
            check_fps(bad)
    t = np.array([0, 20, 10], np.int64)
    with pytest.raises(ExportError, match="reading 2 is timed before reading 1"):
        Resampler(t, np.zeros((3, 2), np.int32), np.ones((3, 2), bool), IDS, fps=30)
    with pytest.raises(ExportError, match="the take holds no readings"):
        Resampler(np.zeros(0, np.int64), np.zeros((0, 2), np.int32), np.zeros((0, 2), bool), IDS, 30)
