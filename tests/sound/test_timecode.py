"""SMPTE timecode (puppet.timecode): labels and frame numbers both ways, exact drop-frame rules."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from puppet.timecode import (RATES, StartTimecode, TimecodeError, frame_to_timecode, rate_of_fps,
                             timecode_rate, timecode_to_frame)

RATE_NAMES = list(RATES)


@settings(max_examples=400, deadline=None, derandomize=True)
@given(st.sampled_from(RATE_NAMES), st.integers(0, 24 * 6 * 17982 - 1))
def test_frame_label_frame_round_trips(name, frame):
    rate = RATES[name]
    frame %= rate.frames_per_day
    assert timecode_to_frame(frame_to_timecode(frame, rate), rate) == frame


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.sampled_from(RATE_NAMES), st.integers(0, 24 * 3600 * 30 - 2))
def test_next_frame_is_the_next_label(name, frame):
    """Consecutive frames get consecutive labels: frames advance by one, wrapping into seconds,
    and at 29.97 drop-frame skipping exactly labels 00 and 01 of minutes not divisible by ten."""
    rate = RATES[name]
    frame %= rate.frames_per_day - 1
    a, b = frame_to_timecode(frame, rate), frame_to_timecode(frame + 1, rate)
    ha, ma, sa, fa = (int(x) for x in a.replace(";", ":").split(":"))
    hb, mb, sb, fb = (int(x) for x in b.replace(";", ":").split(":"))
    skipped = rate.drop and fb == 2 and sb == 0 and mb % 10 != 0  # :00 and :01 were skipped
    if fb != 0 and not skipped:
        assert (hb, mb, sb, fb) == (ha, ma, sa, fa + 1)
    else:
        assert fa == rate.base - 1
        assert (hb * 3600 + mb * 60 + sb) == (ha * 3600 + ma * 60 + sa + 1)
        if rate.drop and sb == 0 and mb % 10:
            assert fb == 2
        else:
            assert fb == 0


@pytest.mark.parametrize("name", RATE_NAMES)
def test_every_label_of_the_first_twenty_minutes(name):
    """Exhaustively: frames 0..20 min are labelled in order, each label once, and back."""
    rate = RATES[name]
    n = 20 * 60 * rate.base
    labels = [frame_to_timecode(f, rate) for f in range(n)]
    assert labels == sorted(labels) and len(set(labels)) == n
    assert all(timecode_to_frame(label, rate) == f for f, label in enumerate(labels))


def test_drop_frame_known_labels():
    df = RATES["29.97"]
    assert frame_to_timecode(0, df) == "00:00:00;00"
    assert frame_to_timecode(1799, df) == "00:00:59;29"
    assert frame_to_timecode(1800, df) == "00:01:00;02"  # 00 and 01 skipped
    assert frame_to_timecode(17982, df) == "00:10:00;00"  # each tenth minute keeps them
    assert frame_to_timecode(17981, df) == "00:09:59;29"
    assert frame_to_timecode(107892, df) == "01:00:00;00"  # one hour = 107 892 frames
    assert timecode_to_frame("01:00:00;00", df) == 107892


def test_drop_frame_stays_on_the_wall_clock():
    """An hour of 29.97 drop-frame labels is an hour of real time within one frame."""
    df = RATES["29.97"]
    frames = timecode_to_frame("01:00:00;00", df)
    assert abs(frames / float(df.fps) - 3600.0) < 1 / 29.97


def test_non_drop_rates():
    assert frame_to_timecode(24 * 3600, "23.976") == "01:00:00:00"
    assert frame_to_timecode(25 * 61 + 3, "25") == "00:01:01:03"
    assert frame_to_timecode(30 * 60, "30") == "00:01:00:00"
    assert timecode_to_frame("00:00:01:23", "24") == 47


@pytest.mark.parametrize("label, rate, words", [
    ("00:01:00;00", "29.97", "skips frames 00 and 01"),
    ("00:01:00;01", "29.97", "skips frames 00 and 01"),
    ("00:00:00:25", "25", "out of range"),
    ("24:00:00:00", "24", "out of range"),
    ("1:00:00:00", "24", "expected HH:MM:SS:FF"),
    ("00:00:00;05", "25", "non-drop"),
])
def test_bad_labels_are_refused(label, rate, words):
    with pytest.raises(TimecodeError, match=words):
        timecode_to_frame(label, rate)


def test_rates_by_name_and_number():
    assert timecode_rate(24000 / 1001).name == "23.976"
    assert timecode_rate("29.97").drop
    assert rate_of_fps(60.0) is None
    with pytest.raises(TimecodeError, match="timecode rate"):
        timecode_rate("50")


def test_start_timecode_given_clock_and_rates():
    start = StartTimecode.given("01:00:00:00", "25")
    assert start.at(25 * 60 + 1) == "01:01:00:01"
    assert start.at_rate("30").label == "01:00:00:00"
    assert start.seconds == 3600.0
    assert StartTimecode("00:10:00;00", "29.97").at_rate("29.97").frame == 17982
    with pytest.raises(TimecodeError):
        StartTimecode("00:01:00;00", "29.97")
    clock = StartTimecode.from_clock("24", unix_ns=0)
    assert timecode_to_frame(clock.label, "24") == clock.frame
