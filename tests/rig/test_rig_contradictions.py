"""Rig files whose keys contradict each other are refused, each error naming the file, the line
and what to change: a servo on a fixed bone, two servos about one axis of a joint, ``skin`` on a
mesh that is not glTF, a limit on a fixed or sensed bone, two limits on one bone. A file saved
with a byte-order mark (Windows editors) reads as the same file without it."""

import pytest

from puppet.rig import RigError, load_rig
from puppet.rig.load import BUILTIN_RIG

TEXT = BUILTIN_RIG.read_text()
NPZ = BUILTIN_RIG.with_name("critter.npz")


def _rig_file(tmp_path, text: str, raw_prefix: bytes = b""):
    path = tmp_path / "rig.toml"
    path.write_bytes(raw_prefix + text.replace('mesh = "critter.npz"', f'mesh = "{NPZ}"').encode())
    return path


def _line_of(text: str, needle: str, after: int = 0) -> int:
    """1-based line of the first line containing ``needle`` at or after line ``after``."""
    lines = text.splitlines()
    return next(i + 1 for i in range(after, len(lines)) if needle in lines[i])


def _refused(tmp_path, text: str, *words) -> RigError:
    with pytest.raises(RigError) as err:
        load_rig(_rig_file(tmp_path, text))
    for word in words:
        assert word in str(err.value)
    return err.value


LIMIT = '\n[[limit]]\nbone = "{bone}"\nswing_deg = 20\n'


def test_a_servo_on_a_fixed_bone_is_refused_naming_its_line(tmp_path):
    text = TEXT.replace('fixed = ["hips"]', 'fixed = ["hips", "neck"]')
    err = _refused(tmp_path, text, "servo 1 is on joint 'neck'", "'fixed'", "holds rigidly")
    assert err.line == _line_of(text, 'joint = "neck"')


def test_guided_calibration_refuses_a_servo_on_a_fixed_bone_before_asking(tmp_path):
    from puppet.rig.guided_calibration import GuidedCalibration

    text = TEXT.replace('fixed = ["hips"]', 'fixed = ["hips", "neck"]')
    with pytest.raises(RigError) as err:
        GuidedCalibration(_rig_file(tmp_path, text))
    assert "servo on joint 'neck', which 'fixed' holds rigidly" in str(err.value)
    assert err.value.field == "servo #1 joint"


def test_two_servos_about_one_axis_of_a_joint_are_refused(tmp_path):
    first = _line_of(TEXT, "id = 3")
    lines = TEXT.splitlines()
    axis = _line_of(TEXT, "axis = ", first)
    lines[axis - 1] = 'axis = "-y"'  # servo 3 on the head now turns about servo 2's axis
    text = "\n".join(lines) + "\n"
    err = _refused(tmp_path, text, "servos 2 and 3 both turn about one axis", "'head'")
    assert err.line == first - 1  # servo 3's [[servo]] line


def test_skin_on_a_mesh_that_is_not_gltf_is_refused(tmp_path):
    text = TEXT.replace('fixed = ["hips"]', 'fixed = ["hips"]\nskin = 0')
    err = _refused(tmp_path, text, "'skin' picks one of a glTF file's skins", "critter.npz")
    assert err.line == _line_of(text, "skin = 0")


@pytest.mark.parametrize("bone, why", [("hips", "which 'fixed' holds rigidly"),
                                       ("neck", "which servo 1 reads")])
def test_a_limit_on_a_fixed_or_sensed_bone_is_refused(tmp_path, bone, why):
    text = TEXT + LIMIT.format(bone=bone)
    err = _refused(tmp_path, text, f"limit on bone {bone!r}", why)
    assert err.line == _line_of(text, "bone = ", _line_of(text, "[[limit]]"))


def test_two_limits_on_one_bone_are_refused_naming_the_second(tmp_path):
    rig = load_rig(BUILTIN_RIG)
    free = rig.skeleton.names[int(rig.free_bones[0])]
    text = TEXT + LIMIT.format(bone=free) + LIMIT.format(bone=free)
    first = _line_of(text, "bone = ", _line_of(text, "[[limit]]"))
    err = _refused(tmp_path, text, f"a second limit on bone {free!r}", f"line {first}")
    assert err.line == _line_of(text, "bone = ", first)


def test_a_rig_file_with_a_byte_order_mark_reads_as_without(tmp_path):
    rig = load_rig(_rig_file(tmp_path, TEXT, raw_prefix=b"\xef\xbb\xbf"))
    assert rig.name == "critter" and len(rig.servo_map) == 15
