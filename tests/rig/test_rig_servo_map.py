"""Servo map: ticks -> angles, calibration, and every validation error naming its line."""

import json

import numpy as np
import pytest

from puppet.rig import Calibration, RigError, load_rig
from puppet.rig.rig_file import read_rig_file
from puppet.rig.servo_map import Servo, ServoMap



def servo(sid, **kw):
    base = dict(id=sid, model="XL330-M288", joint="j", axis=np.array([1.0, 0, 0]))
    base.update(kw)
    return Servo(**base)


def test_angles_follow_sign_gear_zero_and_limits():
    sm = ServoMap([servo(1, zero_ticks=2048), servo(2, sign=-1, zero_ticks=1000),
                   servo(3, gear=2.0, zero_ticks=0), servo(4, limits=(-0.5, 0.5))])
    ticks = np.array([2048 + 1024, 1000 + 512, 4096, 2048 + 2000], np.int32)
    out = np.empty(4)
    assert sm.angles(ticks, out) is out
    np.testing.assert_allclose(out, [np.pi / 2, -np.pi / 4, np.pi, 0.5])


def test_direct_drive_readings_wrap_into_one_turn_around_zero():
    sm = ServoMap([servo(1, zero_ticks=4000)])
    # the servo rebooted: its count restarted near 0; 4000 + 200 wraps to 104.
    np.testing.assert_allclose(sm.angles(np.array([104], np.int32)), [200 * 2 * np.pi / 4096])


def test_calibration_overrides_zero_and_round_trips(tmp_path):
    sm = ServoMap([servo(1), servo(2)])
    cal = Calibration.capture([1, 2], np.array([2100, 1990], np.int32))
    for name in ("cal.toml", "cal.json"):
        saved = cal.save(tmp_path / name)
        loaded = Calibration.load(saved)
        assert loaded.zero_ticks == {1: 2100, 2: 1990}
    sm.calibrate(Calibration({2: 1990}))
    np.testing.assert_array_equal(sm.zero, [2048, 1990])
    np.testing.assert_allclose(sm.angles(np.array([2048, 1990], np.int32)), [0, 0])


def test_ticks_for_inverts_angles():
    sm = ServoMap([servo(1, sign=-1, gear=1.5, zero_ticks=2040), servo(2)])
    angles = np.array([0.3, -1.2])
    np.testing.assert_allclose(sm.angles(sm.ticks_for(angles)), angles, atol=2 * np.pi / 4096)


def test_calibration_errors_name_file_and_field(tmp_path):
    with pytest.raises(RigError, match="calibration file not found"):
        Calibration.load(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[zero_ticks]\n7 = 'x'\n")
    with pytest.raises(RigError, match=r"bad.toml: zero_ticks.7: zero ticks must be a 32-bit integer"):
        Calibration.load(bad)
    (tmp_path / "bad.json").write_text(json.dumps({"other": 1}))
    with pytest.raises(RigError, match=r"bad.json: zero_ticks: missing table"):
        Calibration.load(tmp_path / "bad.json")
    with pytest.raises(RigError, match="duplicate servo ids"):
        Calibration.capture([1, 1], [5, 6])


def broken(tube_rig_dir, old, new):
    original = (tube_rig_dir / "tube.toml").read_text()
    text = original.replace(old, new, 1)
    assert text != original
    path = tube_rig_dir / "broken.toml"
    path.write_text(text)
    return path, text


def line_of(text, needle, occurrence=1):
    hits = [i for i, line in enumerate(text.splitlines(), 1) if needle in line]
    return hits[occurrence - 1]


def test_unknown_joint_names_the_line(tube_rig_dir):
    path, text = broken(tube_rig_dir, 'joint = "bone3"', 'joint = "elbow"')
    with pytest.raises(RigError, match=r"unknown joint 'elbow'") as err:
        load_rig(path)
    assert err.value.line == line_of(text, "[[servo]]", 2)
    assert f"broken.toml:{err.value.line}: servo 5 joint" in str(err.value)


def test_duplicate_servo_id_names_the_line(tube_rig_dir):
    path, text = broken(tube_rig_dir, "id = 6", "id = 3")
    with pytest.raises(RigError, match="duplicate servo id 3") as err:
        read_rig_file(path)
    assert err.value.line == line_of(text, "[[servo]]", 3)


def test_zero_length_axis_names_the_line(tube_rig_dir):
    path, text = broken(tube_rig_dir, "axis = [1, 0, 0]", "axis = [0, 0, 0]")
    with pytest.raises(RigError, match="zero length") as err:
        read_rig_file(path)
    assert err.value.line == line_of(text, "axis = [0, 0, 0]")
    assert err.value.field == "servo 5 axis"


def test_reversed_limits_name_the_line(tube_rig_dir):
    path, text = broken(tube_rig_dir, "limits_deg = [-45, 45]", "limits_deg = [45, -45]")
    with pytest.raises(RigError, match="limits reversed") as err:
        read_rig_file(path)
    assert err.value.line == line_of(text, "limits_deg = [45, -45]")


@pytest.mark.parametrize("old,new,message", [
    ('model = "XL430-W250"', 'model = "AX-12"', "unknown model 'AX-12'"),
    ("sign = -1", "sign = 2", "sign must be 1 or -1"),
    ("gear = 2.0", "gear = 0", r"gear must be a number 0.01..100"),
    ('energy = "spokes"', 'energy = "springs"', "unknown energy 'springs'"),
    ("clusters = 12", "clusters = 0", r"must be an integer 1\.\.5000"),
    ('axis = "-y"', 'axis = "w"', "axis must be x, y, z"),
    ("order = 2", "order = 1", "two servos with order 1"),
    ("vertex = 0", "vertex = 100000", "pin vertex 100000 out of range"),
    ('mesh = "tube.obj"', 'mesh = "tube.stl"', "unknown character format '.stl'"),
    ("zero_ticks = 2000", "zero_ticks = 2000\ncolour = 3", "unknown key"),
])
def test_other_servo_map_errors_name_file_and_field(tube_rig_dir, old, new, message):
    path, _ = broken(tube_rig_dir, old, new)
    with pytest.raises(RigError, match=message) as err:
        load_rig(path)
    assert "broken.toml" in str(err.value)


def test_invalid_toml_is_reported_with_the_file(tube_rig_dir):
    path = tube_rig_dir / "bad.toml"
    path.write_text("name = \n")
    with pytest.raises(RigError, match="bad.toml:1: not valid TOML"):
        read_rig_file(path)


def test_the_takes_calibration_record_round_trips_and_a_bad_one_names_the_take():
    cal = Calibration({12: -4000, 3: 2048, 7: 1900})
    text = cal.to_record()
    assert text == '{"zero_ticks": {"3": 2048, "7": 1900, "12": -4000}}'
    assert Calibration.from_record(text, "t.mcap").zero_ticks == {3: 2048, 7: 1900, 12: -4000}
    assert Calibration.from_record("", "t.mcap").zero_ticks == {}  # a take that stores none
    for bad, message in [("[zero]\n3 = 2048", "t.mcap: calibration record: not valid JSON"),
                         ('{"zero": {}}', "t.mcap: calibration record zero_ticks: missing table"),
                         ('{"zero_ticks": {"3": "x"}}',
                          "t.mcap: calibration record zero_ticks.3: zero ticks must be a 32-bit"),
                         ('{"zero_ticks": {"300": 1}}',
                          "t.mcap: calibration record zero_ticks.300: servo id 300 is not in")]:
        with pytest.raises(RigError) as info:
            Calibration.from_record(bad, "t.mcap")
        assert str(info.value).startswith(message), str(info.value)
        assert info.value.path == "t.mcap"
