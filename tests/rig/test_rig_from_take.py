"""`puppet export TAKE` / `puppet play TAKE` without --rig: the rig map stored in the take, its
character found where the rig file was when recording began, then next to the take; otherwise a
clean error naming the missing file and --rig."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from puppet.reading import Reading
from puppet.cli import main
from puppet.take.header import take_writer
from puppet.replay import RIG_SOURCE_MARK
from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader, TakeWriter


def user_rig(folder):
    """A copy of the built-in rig in ``folder``: my.toml naming critter.npz beside it, and a
    calibration file that moves every zero by 5 ticks."""
    folder.mkdir(parents=True)
    shutil.copy(BUILTIN_RIG.parent / "critter.npz", folder / "critter.npz")
    text = BUILTIN_RIG.read_text().replace('name = "critter"', 'name = "my puppet"')
    (folder / "my.toml").write_text(text.replace('fixed = ["hips"]',
                                                 'calibration = "my.cal.toml"\nfixed = ["hips"]'))
    rig = load_rig(folder / "my.toml")
    zero = "\n".join(f"{i} = {z + 5}" for i, z in zip(rig.servo_map.ids, rig.servo_map.zero))
    (folder / "my.cal.toml").write_text(f"[zero_ticks]\n{zero}\n")
    return folder / "my.toml"


def record(take, rig_path, count=12):
    rig = load_rig(rig_path)
    writer = take_writer(str(take), rig)
    ids = rig.servo_map.ids
    for k in range(count):
        ticks = (rig.servo_map.zero + 40 * np.sin(0.3 * k + np.arange(len(ids)))).astype(np.int32)
        writer.write(Reading(10_000_000 * k, ids, ticks, np.ones(len(ids), bool)))
    writer.close()
    return rig


def export(take, cwd, *extra):
    """`puppet export TAKE --bvh` (plus ``extra``) run from the folder ``cwd``; (result, BVH text)."""
    out = cwd / f"out{len(list(cwd.glob('out*.bvh')))}.bvh"
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(cwd)
        result = CliRunner().invoke(main, ["export", str(take), "--bvh", str(out), *extra])
    return result, out.read_text() if result.exit_code == 0 else ""


def test_export_without_rig_uses_the_rig_stored_in_the_take(tmp_path):
    rig_path = user_rig(tmp_path / "studio")
    take = tmp_path / "takes" / "take.mcap"
    take.parent.mkdir()
    rig = record(take, rig_path)
    meta = TakeReader(take).metadata
    assert meta.rig_map_text.splitlines()[-1] == f"{RIG_SOURCE_MARK}{rig_path.resolve()}"
    assert meta.rig_name == "my puppet"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    result, bvh = export(take, elsewhere)
    assert result.exit_code == 0, result.output
    with_rig, bvh_with_rig = export(take, elsewhere, "--rig", str(rig_path))
    assert with_rig.exit_code == 0
    assert bvh == bvh_with_rig
    assert re.search(r"Frames: [1-9]", bvh)
    assert rig.name == "my puppet"


def test_the_character_next_to_the_take_is_used_when_the_rig_folder_is_gone(tmp_path):
    rig_path = user_rig(tmp_path / "studio")
    take = tmp_path / "takes" / "take.mcap"
    take.parent.mkdir()
    record(take, rig_path)
    shutil.move(tmp_path / "studio", tmp_path / "moved")
    result, _ = export(take, tmp_path)
    assert result.exit_code == 1
    assert "Traceback" not in result.stderr
    error = result.stderr.strip().splitlines()[-1]
    assert error.startswith(f"Error: {take} (rig map):3: mesh: character file not found: looked at "
                            f"{tmp_path / 'studio' / 'critter.npz'} and {take.parent / 'critter.npz'}")
    assert error.endswith(f"recorded with rig file {rig_path.resolve()}; pass --rig with that "
                          "rig file")
    shutil.copy(tmp_path / "moved" / "critter.npz", take.parent / "critter.npz")
    result, bvh = export(take, tmp_path)
    assert result.exit_code == 0, result.output
    assert re.search(r"Frames: [1-9]", bvh)


def test_older_takes_of_the_built_in_rig_still_export_without_rig(tmp_path):
    """A take recorded before the rig file's place was stored: the built-in rig's folder."""
    rig = load_rig(BUILTIN_RIG)
    take = tmp_path / "old.mcap"
    writer = TakeWriter(take, ids=rig.servo_map.ids, models=rig.servo_map.models,
                        rig_map_text=BUILTIN_RIG.read_text(), calibration_text="", rig_name=rig.name)
    for k in range(5):
        writer.write(Reading(10_000_000 * k, rig.servo_map.ids, rig.servo_map.zero.astype(np.int32),
                             np.ones(len(rig.servo_map.ids), bool)))
    writer.close()
    result, bvh = export(take, tmp_path)
    assert result.exit_code == 0, result.output
    assert re.search(r"Frames: [1-9]", bvh)


def test_a_take_without_a_rig_map_asks_for_rig(tmp_path):
    take = tmp_path / "bare.mcap"
    writer = TakeWriter(take, ids=[1, 2], models={1: "XL330-M288", 2: "XL330-M288"},
                        rig_map_text="", calibration_text="", rig_name="creature")
    writer.write(Reading(0, np.array([1, 2]), np.array([2048, 2048], np.int32), np.ones(2, bool)))
    writer.close()
    result, _ = export(take, tmp_path)
    assert result.exit_code == 1
    assert result.stderr.strip() == (f"Error: {take}: the take stores no rig map (recorded with rig "
                                     "'creature' loaded from a character file); pass --rig with "
                                     "that rig's file")


def test_replay_and_perform_read_the_takes_calibration_through_one_codec(tmp_path):
    """record writes the record (take_writer), replay and perform read it back (open_take,
    TakeGoals.from_take); a damaged record is an error naming the take, for both."""
    from puppet.drive.goals import TakeGoals
    from puppet.replay import open_take
    from puppet.rig import Calibration, RigError

    rig = load_rig(BUILTIN_RIG)
    rig.servo_map.calibrate(Calibration({int(i): 2048 + 7 * n for n, i in enumerate(rig.servo_map.ids)}))
    take = tmp_path / "cal.mcap"
    with take_writer(str(take), rig) as writer:
        writer.write(Reading(0, rig.servo_map.ids, rig.servo_map.zero.astype(np.int32),
                             np.ones(len(rig.servo_map.ids), bool)))
    replayed, reader = open_take(take, load_rig(BUILTIN_RIG))
    assert replayed.servo_map.zero.tolist() == rig.servo_map.zero.tolist()
    goals = TakeGoals.from_take(reader, load_rig(BUILTIN_RIG).servo_map)
    np.testing.assert_allclose(goals.goals[0], load_rig(BUILTIN_RIG).servo_map.zero)  # rest pose

    bad = tmp_path / "bad.mcap"
    with TakeWriter(bad, ids=rig.servo_map.ids, models=rig.servo_map.models, rig_map_text="",
                    calibration_text="[zero_ticks]\n1 = 2048\n", rig_name=rig.name) as writer:
        writer.write(Reading(0, rig.servo_map.ids, rig.servo_map.zero.astype(np.int32),
                             np.ones(len(rig.servo_map.ids), bool)))
    with pytest.raises(RigError) as info:
        open_take(bad, load_rig(BUILTIN_RIG))
    assert str(info.value).startswith(f"{bad}: calibration record: not valid JSON")
    with pytest.raises(RigError) as info:
        TakeGoals.from_take(TakeReader(bad), load_rig(BUILTIN_RIG).servo_map)
    assert str(info.value).startswith(f"{bad}: calibration record: not valid JSON")
