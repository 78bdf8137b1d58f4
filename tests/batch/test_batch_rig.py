"""The rig a batch solves a take on is never a guess: without --rig, the take's own (as `puppet
export`), or a refusal naming the rig file it was recorded with; with --rig, that rig, or a
refusal naming both rig files for a take of other servos."""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.take.header import take_writer
from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_DYNAMICS_RIG, BUILTIN_RIG

TAIL_RIG = BUILTIN_RIG.with_name("critter_tail.toml")


def record(take: Path, rig_path: Path, count: int = 10) -> Path:
    """A take recorded as `puppet record --rig rig_path` records it (rig map text and file)."""
    rig = load_rig(rig_path)
    writer = take_writer(str(take), rig)
    ids = rig.servo_map.ids
    for k in range(count):
        ticks = (rig.servo_map.zero + 300 * np.sin(0.3 * k + np.arange(len(ids)))).astype(np.int32)
        writer.write(Reading(33_000_000 * k, ids, ticks, np.ones(len(ids), bool)))
    writer.close()
    return take


@pytest.fixture
def batch(tools):
    """``puppet batch ARGS --json`` in this process (the command's code: end-to-end runs in the
    other batch tests)."""
    def run(*args):
        result = tools.puppet("batch", *args, "--json")
        assert "Traceback" not in result.stderr
        return result
    return run


def export(take: Path, pc2: Path, *rig) -> bytes:
    subprocess.run(["puppet", "export", take, "--pc2", pc2, *rig], check=True,
                   capture_output=True, timeout=300)
    return pc2.read_bytes()


def test_a_take_of_another_rig_file_with_the_same_name_is_solved_on_its_own_rig(tmp_path,
                                                                                batch):
    take = record(tmp_path / "dynamics.mcap", BUILTIN_DYNAMICS_RIG)
    assert load_rig(BUILTIN_DYNAMICS_RIG).name == load_rig(BUILTIN_RIG).name  # both "critter"
    out = tmp_path / "out"
    result = batch(take, "--out", out, "--formats", "pc2", "--workers", 1)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["takes"][0]["state"] == "done"
    own = export(take, tmp_path / "own.pc2")
    built_in = export(take, tmp_path / "built_in.pc2", "--rig", BUILTIN_RIG)
    assert own != built_in  # the two rigs solve this take differently
    assert (out / "dynamics.pc2").read_bytes() == own
    assert json.loads((out / "dynamics.batch.json").read_text())["rig"]["file"] == str(
        BUILTIN_DYNAMICS_RIG)

    # given explicitly, the built-in rig is used, as `puppet export --rig` uses it
    given = batch(take, "--out", out, "--formats", "pc2", "--workers", 1, "--rig", BUILTIN_RIG,
                  "--resume")
    assert given.returncode == 0, given.stderr
    row = json.loads(given.stdout)["takes"][0]
    assert (row["state"], row["reason"]) == (
        "done", f"the rig changed ({BUILTIN_DYNAMICS_RIG} -> {BUILTIN_RIG})")
    assert (out / "dynamics.pc2").read_bytes() == built_in


def test_a_take_whose_rig_is_neither_found_nor_given_is_refused_naming_its_rig_file(tmp_path,
                                                                                   session, batch):
    studio = tmp_path / "studio"
    studio.mkdir()
    shutil.copy(BUILTIN_RIG.parent / "critter.npz", studio / "critter.npz")
    rig_path = studio / "my.toml"
    rig_path.write_text(BUILTIN_RIG.read_text().replace('name = "critter"', 'name = "mine"'))
    takes = tmp_path / "takes"
    takes.mkdir()
    lost = record(takes / "lost.mcap", rig_path)
    (studio / "critter.npz").unlink()
    out = tmp_path / "out"
    result = batch(lost, session[0], "--out", out, "--formats", "bvh", "--workers", 1)
    assert result.returncode == 3  # some takes failed (EXIT_FAILED)
    rows = json.loads(result.stdout)["takes"]
    assert [r["state"] for r in rows] == ["failed", "done"]
    assert f"recorded with rig file {rig_path.resolve()}; pass --rig" in rows[0]["reason"]
    assert rows[0]["outputs"] == [] and not (out / "lost.bvh").exists()
    assert f"recorded with rig file {rig_path.resolve()}" in (out / "lost.log").read_text()


def test_a_given_rig_of_other_servos_is_refused_naming_both_rig_files(tmp_path, session,
                                                                       batch):
    tail = record(tmp_path / "tail.mcap", TAIL_RIG)
    out = tmp_path / "out"
    result = batch(tail, session[0], "--out", out, "--formats", "bvh", "--workers", 1, "--rig",
                   BUILTIN_RIG)
    assert result.returncode == 3  # some takes failed (EXIT_FAILED)
    rows = json.loads(result.stdout)["takes"]
    assert [r["state"] for r in rows] == ["failed", "done"]
    assert "take from another rig" in rows[0]["reason"]
    assert rows[0]["reason"].endswith(f"recorded with rig file {TAIL_RIG}, given --rig "
                                      f"{BUILTIN_RIG}")
    assert not (out / "tail.bvh").exists()


def test_a_take_whose_character_changed_since_recording_is_refused_without_rig(tmp_path,
                                                                                batch):
    studio = tmp_path / "studio"
    studio.mkdir()
    shutil.copy(BUILTIN_RIG.parent / "critter.npz", studio / "critter.npz")
    rig_path = studio / "my.toml"
    rig_path.write_text(BUILTIN_RIG.read_text())
    take = record(tmp_path / "take.mcap", rig_path)
    with np.load(studio / "critter.npz") as data:
        arrays = dict(data)
    arrays["V"] = arrays["V"] * 1.05  # the character edited after the take was recorded
    np.savez(studio / "critter.npz", **arrays)
    out = tmp_path / "out"
    result = batch(take, "--out", out, "--formats", "bvh", "--workers", 1)
    assert result.returncode == 3  # some takes failed (EXIT_FAILED)
    row = json.loads(result.stdout)["takes"][0]
    message = (f"the character found for its rig (recorded with rig file {rig_path.resolve()}) is "
               "not the one it was recorded on")
    assert row["state"] == "failed" and message in row["reason"]
    alone = subprocess.run(["puppet", "export", take, "--bvh", tmp_path / "a.bvh"],
                           capture_output=True, text=True, timeout=300)
    assert alone.returncode == 1 and message in alone.stderr  # the one rule of export and batch
    given = batch(take, "--out", out, "--formats", "bvh", "--workers", 1, "--rig", rig_path)
    assert given.returncode == 0, given.stderr  # named explicitly, the edited rig is used
