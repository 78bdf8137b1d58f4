"""Playback, the one take-to-frames rule: frame counts and times, interpolation (wrap-safe),
flags, long gaps cut and reported, speed, random access, determinism, bad input."""

import numpy as np
import pytest

from puppet.reading import Reading
from puppet.take import MAX_GAP_S, Cut, Playback, TakeError, TakeReader
from puppet.take.playback import check_rate, gap_note

IDS = np.array([1, 2])


def jittered_readings(n=300, seed=0):
    """Readings at about 500 Hz with irregular gaps (including a 50 ms stall)."""
    rng = np.random.default_rng(seed)
    gaps = rng.integers(1_000_000, 3_000_000, size=n)
    gaps[n // 2] = 50_000_000
    t = 7_000_000_000 + np.concatenate([[0], np.cumsum(gaps[:-1])])
    ticks = np.stack([np.arange(n), -7 * np.arange(n)], axis=1).astype(np.int32)
    return t.astype(np.int64), ticks, np.ones((n, 2), bool)


def brute_force(t, ticks, ok, take_t):
    """Ticks and ok at take time take_t by the rule's definition, one servo at a time."""
    j = int(np.searchsorted(t, take_t, side="right")) - 1
    if j == len(t) - 1 or t[j] == take_t:
        return ticks[j].tolist(), ok[j].tolist()
    a = (take_t - t[j]) / (t[j + 1] - t[j])
    out = []
    for s in range(ticks.shape[1]):
        step = (int(ticks[j + 1, s]) - int(ticks[j, s]) + 2048) % 4096 - 2048
        out.append(int(ticks[j, s]) + int(np.floor(a * step + 0.5)))
    return out, (ok[j] & ok[j + 1]).tolist()


@pytest.mark.parametrize("fps,speed", [(60, 1.0), (30, 0.5), (24, 2.0), (1000, 1.0)])
def test_frames_show_the_take_at_their_time(fps, speed):
    t, ticks, ok = jittered_readings()
    frames = Playback(t, ticks, ok, IDS, fps=fps, speed=speed)
    got = list(frames)
    t0, t_last = int(t[0]), int(t[-1])
    n = int(np.floor((t_last - t0) * 1e-9 * fps / speed + 1e-9)) + 1
    assert len(got) == len(frames) == n  # the count is known up front
    for i, r in enumerate(got):
        assert abs(r.t_ns - (t0 + i * speed * 1e9 / fps)) <= 1
        assert (r.ticks.tolist(), r.ok.tolist()) == brute_force(t, ticks, ok, r.t_ns)
        assert r.ticks.dtype == np.int32 and r.ids is frames.ids
    assert got[-1].t_ns <= t_last < got[-1].t_ns + speed * 1e9 / fps
    assert frames.cuts == []


def test_frame_counts_for_the_usual_rates():
    for fps, count in ((24, 73), (25, 76), (30, 91), (50, 151), (60, 181), (7.5, 23)):
        t = np.arange(7, dtype=np.int64) * 500_000_000  # 3 s, a reading every 0.5 s
        frames = Playback(t, np.zeros((7, 2), np.int32), np.ones((7, 2), bool), IDS, fps=fps)
        assert len(frames) == count
        np.testing.assert_array_equal(frames.frame_times_ns(), np.rint(np.arange(count) * 1e9 / fps))
    one = np.zeros((2, 2), np.int32), np.ones((2, 2), bool)
    assert len(Playback(np.array([0, 999_999_999]), *one, IDS, fps=24)) == 24  # 23/24 s < 0.999.. s
    assert len(Playback(np.array([5]), one[0][:1], one[1][:1], IDS, fps=24)) == 1


def test_ticks_are_interpolated_between_irregular_readings():
    t = np.array([0, 10_000_000, 40_000_000, 50_000_000], np.int64)  # 0, 10, 40, 50 ms
    ticks = np.array([[100, 0], [200, 10], [500, 40], [600, 50]], np.int32)
    frames = Playback(t, ticks, np.ones((4, 2), bool), IDS, fps=50)  # every 20 ms: 0, 20, 40 ms
    assert len(frames) == 3
    assert [r.ticks.tolist() for r in frames] == [[100, 0], [300, 20], [500, 40]]
    assert [r.t_ns for r in frames] == [0, 20_000_000, 40_000_000]


def test_interpolation_takes_the_short_way_round_a_wrap():
    t = np.array([0, 10_000_000], np.int64)
    ticks = np.array([[4090, 10], [4, 4090]], np.int32)  # servo 1 wraps up, servo 2 down
    frames = Playback(t, ticks, np.ones((2, 2), bool), IDS, fps=200)  # 0, 5, 10 ms
    assert frames.reading(1).ticks.tolist() == [4090 + 5, 10 - 8]  # +10, -16 halved; never half a turn


def test_the_short_way_round_is_each_models_turn(tmp_path):
    # An AX-12A turns 1228.8 ticks per turn (1024 over 300°): 1000 -> 100 is its short way up
    # through the dead zone (+328.8), where an X-series servo's is 900 ticks down.
    from puppet.take import TakeWriter

    path = tmp_path / "turns.mcap"
    with TakeWriter(path, ids=[1, 2], models={1: "AX-12A", 2: "XL430-W250"}, rig_map_text="",
                    calibration_text="", rig_name="r") as writer:
        for t_ns, ticks in ((0, [1000, 1000]), (10_000_000, [100, 100])):
            writer.write(Reading(t_ns, IDS, np.array(ticks, np.int32), np.ones(2, bool)))
    frames = Playback.of_take(TakeReader(path), IDS, fps=200)  # 0, 5, 10 ms
    assert frames.reading(1).ticks.tolist() == [1000 + 164, 1000 - 450]
    explicit = Playback(np.array([0, 10_000_000]), np.array([[1000, 1000], [100, 100]]),
                        np.ones((2, 2), bool), IDS, fps=200, ticks_per_turn=[1228.8, 4096])
    assert explicit.reading(1).ticks.tolist() == [1164, 550]


def test_a_failed_servo_flags_the_frames_it_touches():
    t = np.array([0, 10_000_000, 20_000_000], np.int64)
    ok = np.array([[True, True], [True, False], [True, True]])
    frames = list(Playback(t, np.zeros((3, 2), np.int32), ok, IDS, fps=400))  # every 2.5 ms
    flagged = [not r.ok[1] for r in frames]
    assert flagged[0] is False and flagged[4] is True and flagged[8] is False
    assert all(flagged[1:8])
    assert all(r.ok[0] for r in frames)


def test_half_speed_plays_twice_as_long():
    take = jittered_readings()
    a = list(Playback(*take, IDS, fps=50, speed=1.0))
    b = list(Playback(*take, IDS, fps=50, speed=0.5))
    assert len(b) == 2 * len(a) - 1
    assert [r.ticks.tolist() for r in b[::2]] == [r.ticks.tolist() for r in a]
    assert [r.t_ns for r in b[::2]] == [r.t_ns for r in a]


def test_random_access_agrees_with_iteration():
    take = jittered_readings()
    frames = Playback(*take, IDS, fps=60)
    got = list(frames)
    for f in (0, 1, 17, len(frames) // 2, len(frames) - 1):
        by_frame, by_time = frames.reading(f), frames.at(frames.frame_ns(f) * 1e-9)
        assert by_frame.t_ns == by_time.t_ns == got[f].t_ns
        assert by_frame.ticks.tolist() == by_time.ticks.tolist() == got[f].ticks.tolist()
    ticks, ok = np.empty(2, np.int32), np.empty(2, bool)
    frames.sample(frames.frame_ns(5), ticks, ok)
    assert ticks.tolist() == got[5].ticks.tolist()
    assert frames.at(-1.0).ticks.tolist() == take[1][0].tolist()   # before the start: the first
    assert frames.at(1e6).ticks.tolist() == take[1][-1].tolist()   # after the end: the last
    with pytest.raises(IndexError):
        frames.reading(len(frames))


def test_playback_of_a_take_is_deterministic(take_path):
    def run():
        frames = Playback.of_take(TakeReader(take_path), [3, 7, 11, 12], fps=60, speed=0.5)
        return len(frames), [(r.t_ns, r.ticks.tolist(), r.ok.tolist()) for r in frames]
    n1, a = run()
    n2, b = run()
    assert a == b
    assert n1 == n2 == len(a)
    assert len(a) == int((199 * 2_000_000 + (199 * 37) % 100) * 1e-9 * 60 / 0.5) + 1


def test_long_gaps_are_cut_and_reported(tmp_path, kit):
    """A stall (or a wrong timestamp that passed every check) plays as MAX_GAP_S, not hours."""
    hour = 3600 * 10**9
    times = [i * 10_000_000 for i in range(10)] + [hour + i * 10_000_000 for i in range(10)]
    rs = [kit.reading_at(i, t) for i, t in enumerate(times)]
    t = np.array(times, np.int64)
    ticks = np.array([r.ticks for r in rs])
    ok = np.array([r.ok for r in rs])
    frames = Playback(t, ticks, ok, kit.IDS, fps=100)
    got = list(frames)
    assert frames.cuts == [Cut(90_000_000, hour - 90_000_000)]
    # 0.09 s, the gap cut to 1 s, then 0.09 s: 1.18 s at 100 fps.
    assert len(got) == len(frames) == 119
    assert frames.duration_s == pytest.approx(1.18)
    assert [r.ticks.tolist() for r in got[:10]] == [r.ticks.tolist() for r in rs[:10]]
    assert [r.ticks.tolist() for r in got[109:]] == [r.ticks.tolist() for r in rs[10:]]
    middle = got[59]  # half way through the cut gap: half way between readings 9 and 10
    assert middle.ticks.tolist() == brute_force(np.array([0, 2]), ticks[9:11], ok[9:11], 1)[0]
    assert np.all(np.diff([r.t_ns for r in got]) > 0)
    assert frames.play_s(hour) == pytest.approx(1.09)  # a marker after the gap moves with it

    path = tmp_path / "gap.mcap"
    with kit.open_writer(path) as w:
        for r in rs:
            w.write(r)
    reader = TakeReader(path)
    assert reader.report.skipped_count == 0
    note = gap_note(t)
    assert note in reader.recovery
    assert note.startswith(f"1 gap(s) between readings longer than {MAX_GAP_S:g} s (the longest "
                           "3599.910 s (1.0 h), 0.090 s into the take)")
    assert len(Playback.of_take(reader, kit.IDS, fps=100)) == 119
    assert gap_note(t[:10]) is None


def test_bad_rates_and_times_are_refused(tmp_path):
    for bad in (0, -24, float("nan"), float("inf"), "abc", 1e300, 1e-300):
        with pytest.raises(TakeError, match="frames per second must be"):
            check_rate(bad, "frames per second", "--fps")
        with pytest.raises(TakeError, match="speed must be"):
            Playback(np.array([0]), np.zeros((1, 2)), np.ones((1, 2), bool), IDS, speed=bad)
    t = np.array([0, 20, 10], np.int64)
    with pytest.raises(TakeError, match="reading 2 is timed before reading 1"):
        Playback(t, np.zeros((3, 2), np.int32), np.ones((3, 2), bool), IDS, fps=30)
    with pytest.raises(TakeError, match="the take holds no readings"):
        Playback(np.zeros(0, np.int64), np.zeros((0, 2), np.int32), np.zeros((0, 2), bool), IDS)
