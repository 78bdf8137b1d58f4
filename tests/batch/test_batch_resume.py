"""--resume is keyed on content: each take's manifest (OUT/<take>.batch.json) records the take's,
the rig's and the character's checksums, the settings that shape its outputs, puppet's version
and the outputs' own checksums; a take is redone when any of them changed, and its row says
why. --dry-run says per take what would be done and why, and writes nothing."""

import hashlib
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from puppet.rig.checksum import character_sha256
from puppet.rig import builtin, load_rig
from puppet.rig.load import BUILTIN_RIG


@pytest.fixture
def batch(tools):
    """``puppet batch ARGS --json`` in this process (what --resume decides lives in the command's
    code; end-to-end runs: the other batch tests and this file's table run)."""
    def run(*args):
        result = tools.puppet("batch", *args, "--json")
        assert "Traceback" not in result.stderr
        return result
    return run


def rows_of(result) -> list[tuple[str, str, str]]:
    """[(take file name, state, reason)] of a --json run."""
    report = json.loads(result.stdout.splitlines()[0])
    return [(Path(r["take"]).name, r["state"], r["reason"]) for r in report["takes"]]


def snapshot(folder: Path) -> dict:
    """Every file below folder: relative name -> (bytes, mtime_ns)."""
    return {str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_resume_redoes_a_take_when_what_shapes_it_changed_and_says_why(tmp_path, critter, tools,
                                                                       batch):
    takes = [tools.write_take(tmp_path / f"t{i}.mcap", critter, seed=i) for i in range(2)]
    out = tmp_path / "out"
    args = [*takes, "--out", out, "--formats", "pc2,bvh", "--workers", 1]
    first = batch(*args)
    assert first.returncode == 0, first.stderr
    assert rows_of(first) == [("t0.mcap", "done", "new"), ("t1.mcap", "done", "new")]
    manifest = json.loads((out / "t0.batch.json").read_text())
    assert manifest["take"]["sha256"] == hashlib.sha256(takes[0].read_bytes()).hexdigest()
    assert manifest["rig"]["file"] == str(BUILTIN_RIG)
    assert manifest["character"]["sha256"] == character_sha256(critter)
    assert manifest["settings"] == {"fps": 30.0, "up": "y", "space": "object",
                                   "layers": None}
    assert manifest["outputs"]["pc2"] == {
        "path": "t0.pc2", "bytes": (out / "t0.pc2").stat().st_size,
        "sha256": hashlib.sha256((out / "t0.pc2").read_bytes()).hexdigest()}

    files = snapshot(out)
    again = batch(*args, "--resume", "--size", 320, 240)  # the size shapes no export
    assert again.returncode == 0, again.stderr
    assert rows_of(again) == [("t0.mcap", "skipped", "up to date"),
                              ("t1.mcap", "skipped", "up to date")]
    assert snapshot(out) == files

    # settings that shape the files: each redone take says what changed. One setting changes
    # per run, the earlier changes kept (each run's reason names that setting alone); the last
    # run goes back to the defaults, and names all three.
    kept = []
    for option, value, reason in (("--fps", 24, "fps 30 -> 24"), ("--up", "z", "up y -> z"),
                                  ("--space", "model", "space object -> model")):
        kept += [option, value]
        changed = batch(*args, "--resume", *kept)
        assert changed.returncode == 0, changed.stderr
        assert [r[1:] for r in rows_of(changed)] == [("done", reason)] * 2
    back = batch(*args, "--resume")
    assert [r[1:] for r in rows_of(back)] == [
        ("done", "fps 24 -> 30; up z -> y; space model -> object")] * 2
    more = batch(*args[:-4], "--formats", "pc2,bvh,gltf", "--workers", 1, "--resume")
    assert [r[1:] for r in rows_of(more)] == [("done", f"{t.stem}.glb not made yet")
                                              for t in takes]

    # the take's content (not its time), an output changed or gone, another puppet version
    tools.write_take(takes[0], critter, seed=5)
    (out / "t1.bvh").write_bytes((out / "t1.bvh").read_bytes() + b"\n")
    record = json.loads((out / "t1.batch.json").read_text())
    record["puppet"] = "0.0.1"
    (out / "t1.batch.json").write_text(json.dumps(record))
    redone = batch(*args, "--resume")
    assert redone.returncode == 0, redone.stderr
    assert rows_of(redone) == [("t0.mcap", "done", "the take changed"),
                               ("t1.mcap", "done", "puppet 0.0.1 -> 0.1.0; t1.bvh changed since "
                                                   "it was written")]
    (out / "t0.pc2").unlink()
    gone = batch(*args, "--resume")
    assert rows_of(gone)[0][1:] == ("done", "t0.pc2 is missing")
    assert rows_of(gone)[1][1] == "skipped"

    # the rig: solving on another rig file redoes every take, naming both files
    rig_copy = tmp_path / "rig" / "critter.toml"
    rig_copy.parent.mkdir()
    rig_copy.write_text(BUILTIN_RIG.read_text().replace(
        'mesh = "critter.npz"', f'mesh = "{BUILTIN_RIG.parent / "critter.npz"}"'))
    other_rig = batch(*args, "--resume", "--rig", rig_copy)
    assert other_rig.returncode == 0, other_rig.stderr
    assert [r[1:] for r in rows_of(other_rig)] == [
        ("done", f"the rig changed ({BUILTIN_RIG} -> {rig_copy})")] * 2


def test_dry_run_says_what_would_be_done_and_writes_nothing(tmp_path, critter, tools,
                                                            batch):
    takes = [tools.write_take(tmp_path / f"t{i}.mcap", critter, seed=i) for i in range(2)]
    out = tmp_path / "out"
    args = [*takes, "--out", out, "--formats", "pc2", "--workers", 1]
    nothing_yet = batch(*args, "--dry-run")
    assert nothing_yet.returncode == 0, nothing_yet.stderr
    assert rows_of(nothing_yet) == [("t0.mcap", "to do", "new"), ("t1.mcap", "to do", "new")]
    assert not out.exists()
    assert batch(*args).returncode == 0
    tools.write_take(takes[1], critter, seed=9)
    files = snapshot(out)
    planned = batch(*args, "--resume", "--dry-run")
    assert planned.returncode == 0, planned.stderr
    assert rows_of(planned) == [("t0.mcap", "skipped", "up to date"),
                                ("t1.mcap", "to do", "the take changed")]
    assert snapshot(out) == files
    table = subprocess.run(["puppet", "batch", *map(str, args), "--fps", "25", "--dry-run"],
                           capture_output=True, text=True, timeout=600)
    assert table.returncode == 0, table.stderr
    lines = table.stdout.splitlines()
    assert lines[1].split()[:2] == [str(takes[0]), "to"]
    assert lines[1].endswith("fps 30 -> 25")
    assert lines[2].endswith("the take changed; fps 30 -> 25")
    assert lines[-1] == f"dry run: 2 to do; nothing written in {out}"
    assert snapshot(out) == files


def test_the_character_checksum_follows_the_character_not_its_file(tmp_path):
    folder = tmp_path / "copy"
    folder.mkdir()
    (folder / "critter.npz").write_bytes((BUILTIN_RIG.parent / "critter.npz").read_bytes())
    (folder / "my.toml").write_text(BUILTIN_RIG.read_text())
    assert character_sha256(load_rig(folder / "my.toml")) == character_sha256(builtin())
    with np.load(folder / "critter.npz") as data:
        arrays = dict(data)
    arrays["V"] = arrays["V"] * 1.01
    np.savez(folder / "critter.npz", **arrays)
    assert character_sha256(load_rig(folder / "my.toml")) != character_sha256(builtin())


def test_keys_shape_the_gltf_as_in_export_and_a_change_redoes_it(tmp_path, critter, tools,
                                                                 batch):
    take = tools.write_take(tmp_path / "t.mcap", critter)
    out = tmp_path / "out"
    args = [take, "--out", out, "--formats", "gltf,bvh", "--workers", 1]
    assert batch(*args).returncode == 0
    reduced = batch(*args, "--resume", "--keys", "0.5")
    assert reduced.returncode == 0, reduced.stderr
    assert rows_of(reduced) == [("t.mcap", "done", "keys (none) -> 0.5")]
    subprocess.run(["puppet", "export", take, "--gltf", tmp_path / "alone.glb", "--keys", "0.5"],
                   check=True, capture_output=True, timeout=300)
    assert (out / "t.glb").read_bytes() == (tmp_path / "alone.glb").read_bytes()
    log = (out / "t.log").read_text()  # the export's report: keys kept per joint
    assert "  gltf keys within 0.5° and " in log and f"  gltf: {out / 't.glb'} (" in log
    assert rows_of(batch(*args, "--resume", "--keys", "0.5"))[0][1] == "skipped"
    for bad, words in ((["--keys-units", "0.1"], "--keys-units: needs --keys"),
                       (["--keys", "0.5", "--formats", "bvh"], "--keys: reduces the glTF's keys")):
        refused = batch(*args, *bad)
        assert refused.returncode == 1 and f"Error: {words}" in refused.stderr


def test_a_given_rig_s_calibration_file_is_part_of_the_rig(tmp_path, critter, tools,
                                                           batch):
    take = tools.write_take(tmp_path / "t.mcap", critter)  # records no calibration of its own
    rig_path = tmp_path / "rig" / "my.toml"
    rig_path.parent.mkdir()
    (rig_path.parent / "critter.npz").write_bytes((BUILTIN_RIG.parent / "critter.npz").read_bytes())
    rig_path.write_text(BUILTIN_RIG.read_text().replace(
        'fixed = ["hips"]', 'calibration = "my.cal.toml"\nfixed = ["hips"]'))
    zero = "\n".join(f"{i} = {z}" for i, z in zip(critter.servo_map.ids, critter.servo_map.zero))
    (rig_path.parent / "my.cal.toml").write_text(f"[zero_ticks]\n{zero}\n")
    args = [take, "--out", tmp_path / "out", "--formats", "bvh", "--workers", 1, "--rig", rig_path]
    assert batch(*args).returncode == 0
    assert rows_of(batch(*args, "--resume"))[0][1] == "skipped"
    shifted = "\n".join(f"{i} = {z + 40}" for i, z in zip(critter.servo_map.ids,
                                                         critter.servo_map.zero))
    (rig_path.parent / "my.cal.toml").write_text(f"[zero_ticks]\n{shifted}\n")
    again = batch(*args, "--resume")
    assert rows_of(again) == [("t.mcap", "done", f"the rig changed ({rig_path})")]
