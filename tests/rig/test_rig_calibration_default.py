"""A rig file that names no calibration file reads ``<name>.calibration.toml`` beside it when
that exists (where ``puppet calibrate`` writes it, as the README says); a ``calibration`` key
wins; the file is one of the rig's inputs (no output may replace it)."""

from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_RIG
from puppet.rig.rig_file import default_calibration, input_files

TEXT = BUILTIN_RIG.read_text().replace('mesh = "critter.npz"',
                                       f'mesh = "{BUILTIN_RIG.with_name("critter.npz")}"')


def _calibration(path, zero: int):
    rig = load_rig(BUILTIN_RIG)
    path.write_text("# puppet calibration\n[zero_ticks]\n"
                    + "".join(f"{int(i)} = {zero}\n" for i in rig.servo_map.ids))
    return path


def test_a_rig_reads_the_calibration_beside_it_when_it_names_none(tmp_path):
    rig_path = tmp_path / "my.toml"
    rig_path.write_text(TEXT)
    assert default_calibration(rig_path) == tmp_path / "my.calibration.toml"
    assert load_rig(rig_path).calibration.path is None  # none there yet
    _calibration(tmp_path / "my.calibration.toml", 2100)
    rig = load_rig(rig_path)
    assert rig.calibration.path == tmp_path / "my.calibration.toml"
    assert rig.servo_map.zero.tolist() == [2100] * len(rig.servo_map)
    assert tmp_path / "my.calibration.toml" in input_files(rig_path)


def test_a_calibration_key_wins_over_the_file_beside_the_rig(tmp_path):
    rig_path = tmp_path / "my.toml"
    rig_path.write_text('calibration = "other.toml"\n' + TEXT)
    _calibration(tmp_path / "my.calibration.toml", 2100)
    _calibration(tmp_path / "other.toml", 1990)
    rig = load_rig(rig_path)
    assert rig.calibration.path == tmp_path / "other.toml"
    assert rig.servo_map.zero.tolist() == [1990] * len(rig.servo_map)
