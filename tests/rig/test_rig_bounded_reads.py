"""Odd input ends in an error, never a hang: ``rig init`` of a FIFO, of a glTF whose buffer is a
device (``/dev/zero`` never ends), of a model of 50 000 joints (refused from its JSON's counts,
before the document is parsed into objects: ``puppet.rig.gltf.MAX_NODES``/``MAX_JOINTS``);
``rig axes --all`` of more turns than a sheet holds (``puppet.render.axes_sheet.MAX_PAIRS``)
shows the first ones, its progress, says how many it left out and how to see the next ones (a
real generated model of 1000 joints: bounded, one sheet, --from for the next)."""

import json
import os
import subprocess
import sys

import pytest
from click.testing import CliRunner

from puppet.rig.errors import RigError
from puppet.rig.gltf import MAX_JOINTS, MAX_NODES, read_gltf


def _puppet(*args):
    # A subprocess: were the file read, the command would block or never end; generous timeout.
    return subprocess.run([sys.executable, "-P", "-c", "from puppet.cli import main; main()",
                           *map(str, args)], capture_output=True, text=True, timeout=300)


def test_rig_init_of_a_fifo_is_refused_without_reading_it(tmp_path):
    os.mkfifo(tmp_path / "beast.glb")
    result = _puppet("rig", "init", tmp_path / "beast.glb", "--out", tmp_path / "beast.toml")
    assert result.returncode == 1, result.stderr
    assert "is a FIFO (named pipe), not a glTF file" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "beast.toml").exists()


def test_rig_init_of_a_gltf_whose_buffer_is_a_device_is_refused(tmp_path, character):
    doc, _ = character.document(character.beast(), binary=False)
    doc.buffers[0].uri = "/dev/zero"
    doc.save_json(str(tmp_path / "beast.gltf"))
    result = _puppet("rig", "init", tmp_path / "beast.gltf", "--out", tmp_path / "beast.toml")
    assert result.returncode == 1, result.stderr
    assert "buffers[0].uri: buffer file '/dev/zero'" in result.stderr
    assert "not a regular file" in result.stderr and "Traceback" not in result.stderr


def _many_joints(path, joints: int):
    """A glTF document of ``joints`` nodes in one chain, all joints of one skin (no mesh data
    is needed: the counts are refused first)."""
    nodes = [{"name": f"j{i}", **({"children": [i + 1]} if i + 1 < joints else {})}
             for i in range(joints)]
    doc = {"asset": {"version": "2.0"}, "nodes": nodes, "skins": [{"joints": list(range(joints))}]}
    path.write_text(json.dumps(doc))
    return path


def test_a_model_of_50000_joints_is_refused_from_its_counts(tmp_path):
    with pytest.raises(RigError) as err:
        read_gltf(_many_joints(tmp_path / "many.gltf", 50_000))
    assert f"50000 nodes; at most {MAX_NODES} are read" in str(err.value)
    with pytest.raises(RigError) as err:
        read_gltf(_many_joints(tmp_path / "joints.gltf", MAX_JOINTS + 1))
    assert f"{MAX_JOINTS + 1} joints; at most {MAX_JOINTS} are read" in str(err.value)
    assert err.value.field == "skins[0].joints"


def test_rig_axes_shows_at_most_a_sheet_of_pairs_and_says_what_it_left_out(
        tmp_path, character, monkeypatch):
    import imageio.v3 as iio

    import puppet.render.axes_sheet as axes_sheet
    from puppet.cli import main
    from puppet.render.axes_sheet import RenderInputError, render_turn_sheet

    glb = character.write_glb(tmp_path / "beast.glb")
    assert _puppet("rig", "init", glb).returncode == 0
    monkeypatch.setattr(axes_sheet, "MAX_PAIRS", 4)  # a sheet's bound, made small to test it
    result = CliRunner().invoke(main, ["rig", "axes", str(tmp_path / "beast.toml"), "--all",
                                       "--out", str(tmp_path / "sheet.png")])
    assert result.exit_code == 0, result.output
    turns = 3 * len(character.NAMES)
    assert (f"warning: {turns} turns to show; one sheet holds 4 pairs" in result.output
            and f"{turns - 4} left out" in result.output)
    assert "8 panels: 4 pairs" in result.output
    assert iio.imread(tmp_path / "sheet.png").shape[0] == 2 * 260
    with pytest.raises(RenderInputError, match="5 pairs; a sheet holds at most 4"):
        render_turn_sheet(None, None, None, None, None, None, [None] * 5)


def test_rig_axes_all_of_a_real_1000_joint_model_is_one_bounded_sheet_with_a_next_one(
        tmp_path, character):
    import imageio.v3 as iio

    from puppet.render.axes_sheet import MAX_PAIRS

    from puppet.cli import main

    def puppet_here(*args):  # the commands after the first sheet: in this process (no start-up)
        return CliRunner().invoke(main, list(map(str, args)))

    glb = character.write_chain_glb(tmp_path / "snake.glb", 1000)
    made = puppet_here("rig", "init", glb)
    assert made.exit_code == 0 and "1000 joints" in made.stdout, made.output
    rig = tmp_path / "snake.toml"
    sheet = tmp_path / "sheet.png"
    first = _puppet("rig", "axes", rig, "--all", "--out", sheet)   # the command as a user runs it
    assert first.returncode == 0, first.stderr
    assert (f"warning: 3000 turns to show; one sheet holds {MAX_PAIRS} pairs" in first.stderr
            and f"showing turns 1 to {MAX_PAIRS}" in first.stderr
            and f"{3000 - MAX_PAIRS} left out; --from {MAX_PAIRS + 1} shows the next ones" in first.stderr)
    assert "axes sheet" in first.stderr  # the progress bar's label
    assert f"{2 * MAX_PAIRS} panels: {MAX_PAIRS} pairs" in first.stdout
    assert iio.imread(sheet).shape[:2] == (MAX_PAIRS // 2 * 260, 4 * 320)
    last = puppet_here("rig", "axes", rig, "--all", "--from", 2991, "--out", tmp_path / "last.png")
    assert last.exit_code == 0, last.output
    assert "showing turns 2991 to 3000" in last.stderr and "2990 left out" in last.stderr
    assert "--from 3001" not in last.stderr and "20 panels: 10 pairs" in last.stdout
    assert iio.imread(tmp_path / "last.png").shape[:2] == (10 // 2 * 260, 4 * 320)
    beyond = puppet_here("rig", "axes", rig, "--all", "--from", 3001, "--out", tmp_path / "none.png")
    assert beyond.exit_code == 1 and isinstance(beyond.exception, SystemExit)   # an Error line, no traceback
    assert f"Error: --from 3001: {rig} has 3000 turns to show" in beyond.stderr
    assert not (tmp_path / "none.png").exists()
