"""Motion sources and the motion / fault file formats (errors name the file and line)."""

from __future__ import annotations

import numpy as np
import pytest

import hw_sim
from hw_sim.faults import Fault, FaultError, FaultSchedule, parse_ids
from hw_sim.motion import Keyframes, Replay, Spin, Walk, make_motion


def test_keyframes_interpolate_and_loop(tmp_path):
    path = tmp_path / "keys.csv"
    path.write_text("# keyframes\nt, 1, 2\n0.0, 2048, 0\n1.0, 3048, 8192\n")
    keys = Keyframes.from_file(path)
    assert keys.position(1, 0.5) == pytest.approx(2548)
    assert keys.position(2, 0.25) == pytest.approx(2048)
    assert keys.position(1, 1.5) == pytest.approx(2548)  # loops over its 1 s duration
    assert keys.position(9, 0.5) == 2048
    assert isinstance(make_motion(str(path)), Keyframes)


@pytest.mark.parametrize("text, line, needle", [
    ("x, 1\n0, 1\n", 1, "header must start with 't'"),
    ("t, 1, 2\n0, 5\n", 2, "expected 3 columns"),
    ("t, 1\n0, 5\n0, 6\n", 3, "not after"),
    ("t, 1\n# c\n0.5, abc\n", 3, "not a number"),
])
def test_keyframe_errors_name_file_and_line(tmp_path, text, line, needle):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(hw_sim.MotionFileError, match=needle) as info:
        Keyframes.from_file(path)
    assert (info.value.path, info.value.line) == (str(path), line)
    assert str(info.value).startswith(f"{path}:{line}:")


def test_unknown_motion_names_the_choices():
    with pytest.raises(hw_sim.MotionFileError, match="wave"):
        make_motion("no-such-motion")


def test_replay_from_npz_sample_and_hold(tmp_path):
    path = tmp_path / "take.npz"
    np.savez(path, t_ns=np.array([10_000_000_000, 10_010_000_000, 10_020_000_000]),
             ids=np.array([4, 5]), ticks=np.array([[1, 2], [3, 4], [5, 6]]))
    replay = Replay.from_file(path)
    assert [replay.position(4, t) for t in (0.0, 0.005, 0.012, 5.0)] == [1, 1, 3, 5]
    assert isinstance(make_motion(f"replay:{path}"), Replay)


def test_builtin_walk_and_spin():
    walk = Walk(period_s=1.0)
    assert walk.position(1, 0.0) == pytest.approx(walk.position(4, 0.5))  # legs half a cycle apart
    spin = Spin(rpm=60)
    assert spin.position(1, 2.0) == pytest.approx(2048 + 2 * 4096)  # passes 4095 and keeps counting
    assert spin.position(2, 1.0) == pytest.approx(2048 - 4096)


def test_replay_drives_the_bus(tmp_path, open_sdk):
    path = tmp_path / "take.csv"
    path.write_text("t,1\n0,4500\n")
    with hw_sim.serve([1], motion=f"replay:{path}") as bus:
        sdk = open_sdk(bus.port)
        # the servo powered up with its shaft at 4500: re-based into one turn
        assert sdk.packet.read4ByteTxRx(sdk.port, 1, 132)[0] == 4500 - 4096


@pytest.mark.parametrize("text, needle", [
    ("0.5 dorp ids=1\n", "unknown fault kind 'dorp'"),
    ("abc drop\n", "start time 'abc'"),
    ("1 drop ids=3-1\n", "backwards"),
    ("1 drop p=2\n", "probability"),
    ("1 noise amp=2\n", "unknown parameter 'amp'"),
    ("1 hardware_error error=melted\n", "overload"),
    ("1 drop ids\n", "key=value"),
])
def test_fault_file_errors_name_file_and_line(tmp_path, text, needle):
    path = tmp_path / "f.txt"
    path.write_text("# header\n\n" + text)
    with pytest.raises(hw_sim.FaultFileError, match=needle) as info:
        FaultSchedule.from_file(path)
    assert info.value.line == 3
    assert str(path) in str(info.value)


def test_fault_file_parses():
    assert parse_ids("1-3,7") == [1, 2, 3, 7]
    f = Fault.make("hardware_error", [4], error="overheating")
    assert f.params["bits"] == 0x04
    with pytest.raises(FaultError, match="unknown fault kind"):
        Fault.make("melt")


def test_inject_validates_in_the_caller(bus):
    with pytest.raises(FaultError, match="unknown parameter"):
        bus.inject("drop", ids=[1], chance=0.5)


def test_replay_of_a_recorded_puppet_take(tmp_path, open_sdk):
    from puppet.reading import Reading
    from puppet.take import TakeWriter

    path = tmp_path / "take.mcap"
    writer = TakeWriter(path, ids=[1, 2], models={1: "XL330-M288", 2: "XL330-M288"},
                        rig_map_text="", calibration_text="", rig_name="test")
    for k, ticks in enumerate([[100, 5000], [200, 5100], [300, -20]]):
        writer.write(Reading(t_ns=5_000_000_000 + k * 10_000_000, ids=np.array([1, 2]),
                             ticks=np.array(ticks, dtype=np.int32), ok=np.ones(2, dtype=bool)))
    writer.close()
    replay = Replay.from_file(path)
    assert [replay.position(2, t) for t in (0.0, 0.011, 0.025, 9.0)] == [5000, 5100, -20, -20]
    cut = tmp_path / "cut.mcap"  # a take whose writer was killed: no summary, torn tail
    data = path.read_bytes()
    cut.write_bytes(data[:data.rindex(b"\x00\x01\x00\x00") + 8])
    assert Replay.from_file(cut).position(1, 0.0) == 100
    with pytest.raises(hw_sim.MotionFileError, match="not a readable puppet take"):
        bad = tmp_path / "bad.mcap"
        bad.write_bytes(b"not mcap at all")
        Replay.from_file(bad)


def test_a_motion_file_that_is_not_text_or_not_a_file_is_named(tmp_path):
    import os

    binary = tmp_path / "motion.csv"
    binary.write_bytes(b"t, 1\n0, 5\n\xf1\xff\n")
    for spec in (str(binary), f"replay:{binary}"):
        with pytest.raises(hw_sim.MotionFileError) as info:
            hw_sim.motion.make_motion(spec)
        assert str(info.value) == f"{binary}:3: not UTF-8 text (a motion file is a CSV of ticks)"
    for name in ("fifo.csv", "fifo.mcap", "fifo.npz"):  # each reader of a replay
        fifo = tmp_path / name
        os.mkfifo(fifo)  # read, it would block for ever
        with pytest.raises(hw_sim.MotionFileError, match="not a regular file"):
            hw_sim.motion.make_motion(f"replay:{fifo}")
