"""PlaybackClock: fixed-rate frames from a take's timestamps, deterministic, at any speed."""

import numpy as np
import pytest

from puppet.reading import Reading
from puppet.take import PlaybackClock, TakeReader, pace


def jittered_readings(n=300, seed=0):
    """Readings at about 500 Hz with irregular gaps (including a 50 ms stall)."""
    rng = np.random.default_rng(seed)
    gaps = rng.integers(1_000_000, 3_000_000, size=n)
    gaps[n // 2] = 50_000_000
    t = 7_000_000_000 + np.concatenate([[0], np.cumsum(gaps[:-1])])
    ids = np.array([1, 2])
    return [Reading(int(ti), ids, np.array([i, -i], np.int32), np.ones(2, bool))
            for i, ti in enumerate(t)]


def brute_force(readings, take_t, mode):
    t = np.array([r.t_ns for r in readings])
    j = int(np.searchsorted(t, take_t, side="right")) - 1
    if mode == "nearest" and j + 1 < len(t) and t[j + 1] - take_t < take_t - t[j]:
        j += 1
    return j


@pytest.mark.parametrize("mode", ["hold", "nearest"])
@pytest.mark.parametrize("fps,speed", [(60, 1.0), (30, 0.5), (24, 2.0), (1000, 1.0)])
def test_frames_show_the_right_reading(mode, fps, speed):
    rs = jittered_readings()
    frames = list(PlaybackClock(rs, fps=fps, speed=speed, mode=mode))
    t0, t_last = rs[0].t_ns, rs[-1].t_ns
    n = int(np.floor((t_last - t0) * 1e-9 * fps / speed + 1e-9)) + 1
    assert len(frames) == n
    for i, f in enumerate(frames):
        assert f.index == i
        assert f.t_s == pytest.approx(i / fps, abs=1e-12)
        assert abs(f.take_t_ns - (t0 + i * speed * 1e9 / fps)) <= 1
        assert f.reading is rs[brute_force(rs, f.take_t_ns, mode)]
    assert frames[-1].take_t_ns <= t_last < frames[-1].take_t_ns + speed * 1e9 / fps


def test_half_speed_plays_twice_as_long():
    rs = jittered_readings()
    a = list(PlaybackClock(rs, fps=50, speed=1.0))
    b = list(PlaybackClock(rs, fps=50, speed=0.5))
    assert len(b) == 2 * len(a) - 1
    assert [f.reading for f in b[::2]] == [f.reading for f in a]
    assert b[-1].t_s == pytest.approx(2 * a[-1].t_s)


def test_playback_of_a_take_is_deterministic(take_path):
    def run():
        r = TakeReader(take_path)
        clock = PlaybackClock(r, fps=60, speed=0.5)
        return len(clock), [(f.index, f.take_t_ns, f.reading.t_ns, f.reading.ticks.tolist())
                            for f in clock]
    n1, a = run()
    n2, b = run()
    assert a == b
    assert n1 == n2 == len(a)
    assert len(a) == int((199 * 2_000_000 + (199 * 37) % 100) * 1e-9 * 60 / 0.5) + 1


def test_span_and_frame_count():
    rs = jittered_readings()
    t0 = rs[0].t_ns
    clock = PlaybackClock(rs, fps=100, start_s=0.1, end_s=0.3)
    frames = list(clock)
    assert frames[0].take_t_ns == t0 + 100_000_000
    assert frames[-1].take_t_ns == t0 + 300_000_000
    assert len(frames) == 21 == clock.frame_count(rs[-1].t_ns - t0)
    assert list(PlaybackClock([], fps=30)) == []
    single = list(PlaybackClock(rs[:1], fps=30))
    assert len(single) == 1 and single[0].reading is rs[0]


def test_bad_arguments():
    with pytest.raises(ValueError, match="fps must be > 0"):
        PlaybackClock([], fps=0)
    with pytest.raises(ValueError, match="speed must be > 0"):
        PlaybackClock([], speed=-1)
    with pytest.raises(ValueError, match="mode must be"):
        PlaybackClock([], mode="linear")
    with pytest.raises(ValueError, match="bad span"):
        PlaybackClock([], start_s=2.0, end_s=1.0)
    with pytest.raises(TypeError, match="needs a TakeReader"):
        len(PlaybackClock([], fps=30))


def test_pace_waits_for_each_frame_on_the_injected_clock():
    now = [100.0]
    slept = []

    def sleep(s):
        slept.append(s)
        now[0] += s

    frames = list(PlaybackClock(jittered_readings(50), fps=10))
    out = []
    for f in pace(frames, clock=lambda: now[0], sleep=sleep):
        out.append((f.index, now[0]))
        now[0] += 0.03  # work per frame
    assert [i for i, _ in out] == list(range(len(frames)))
    for i, t in out:
        assert t == pytest.approx(100.0 + i / 10)
    assert all(s == pytest.approx(0.07) for s in slept)


def test_long_gaps_are_cut_and_reported(tmp_path, kit):
    """A stall (or a wrong timestamp that passed every check) plays as max_gap_s, not hours."""
    hour = 3600 * 10**9
    times = [i * 10_000_000 for i in range(10)] + [hour + i * 10_000_000 for i in range(10)]
    rs = [kit.reading_at(i, t) for i, t in enumerate(times)]
    clock = PlaybackClock(rs, fps=100, max_gap_s=0.5)
    frames = list(clock)
    assert clock.cuts == [(90_000_000, hour - 90_000_000)]
    # 0.09 s, the gap cut to 0.5 s, then 0.09 s: 0.68 s at 100 fps.
    assert len(frames) == 69
    assert [f.reading.t_ns for f in frames[:10]] == times[:10]
    assert all(f.reading is rs[9] for f in frames[9:59])  # held through the cut gap
    assert [f.reading.t_ns for f in frames[59:]] == times[10:]
    assert frames[59].take_t_ns == hour
    assert np.all(np.diff([f.take_t_ns for f in frames]) > 0)

    path = tmp_path / "gap.mcap"
    with kit.open_writer(path) as w:
        for r in rs:
            w.write(r)
    reader = TakeReader(path)
    assert reader.report.skipped_count == 0
    assert "1 gap(s) between readings longer than 1 s" in reader.recovery
    clock = PlaybackClock(reader, fps=100)  # the default cut, 1 s
    assert len(clock) == len(list(clock)) == 119


def test_bad_max_gap():
    with pytest.raises(ValueError, match="max_gap_s must be > 0"):
        PlaybackClock([], max_gap_s=0)
