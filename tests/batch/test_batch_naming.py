"""Output names: takes of one file name in different folders do not collide. Outputs mirror each
take's folder below the folder its argument names (a folder, or a pattern's leading folders);
two takes that would still write the same files are refused before any work, naming both."""

import json

import pytest


@pytest.fixture
def batch(tools, monkeypatch):
    """``puppet batch ARGS --json`` in this process, from the folder ``cwd`` (the command's
    code: end-to-end runs in the other batch tests)."""
    def run(*args, cwd=None):
        if cwd is not None:
            monkeypatch.chdir(cwd)
        return tools.puppet("batch", *args, "--json")
    return run


def test_takes_of_one_name_in_different_folders_mirror_their_folders(tmp_path, critter, tools,
                                                                     batch):
    shoot = tmp_path / "shoot"
    for day in ("day1", "day2", "day2/pickups"):
        (shoot / day).mkdir(parents=True)
    takes = [tools.write_take(shoot / day / "take.mcap", critter, seed=i)
             for i, day in enumerate(("day1", "day2", "day2/pickups"))]
    out = tmp_path / "out"
    result = batch("shoot/**/take.mcap", "--out", out, "--formats", "pc2", "--workers", 1,
                   cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    outputs = {r["take"]: r["outputs"] for r in json.loads(result.stdout)["takes"]}
    expected = [out / "day1" / "take.pc2", out / "day2" / "take.pc2",
                out / "day2" / "pickups" / "take.pc2"]
    assert outputs == {str(t.relative_to(tmp_path)): [str(p)] for t, p in zip(takes, expected)}
    for take, pc2 in zip(takes, expected):
        serial = tools.serial(take, tmp_path / f"serial_{take.parent.name}", ("pc2",))
        assert pc2.read_bytes() == serial["pc2"]
        assert pc2.with_suffix(".log").exists() and pc2.with_suffix(".batch.json").exists()

    # a folder argument: its takes' files go straight into OUT
    flat = batch(shoot / "day1", "--out", tmp_path / "flat", "--formats", "pc2", "--workers", 1)
    assert flat.returncode == 0, flat.stderr
    assert json.loads(flat.stdout)["takes"][0]["outputs"] == [str(tmp_path / "flat" / "take.pc2")]


def test_two_takes_that_would_write_the_same_files_are_refused_naming_both(tmp_path, critter,
                                                                           tools, batch):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
    a = tools.write_take(tmp_path / "a" / "take.mcap", critter)
    b = tools.write_take(tmp_path / "b" / "take.mcap", critter)
    out = tmp_path / "out"
    result = batch(a, b, "--out", out, "--formats", "pc2")
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert (f"Error: {b}: same name as {a}: both would write {out / 'take'}.*; name their "
            "folders with one pattern") in result.stderr
    assert list(out.iterdir()) == []


def test_a_file_where_a_mirrored_folder_goes_is_refused_naming_it(tmp_path, critter, tools,
                                                                  batch):
    (tmp_path / "shoot" / "day1").mkdir(parents=True)
    tools.write_take(tmp_path / "shoot" / "day1" / "take.mcap", critter)
    out = tmp_path / "out"
    out.mkdir()
    (out / "day1").write_text("not a folder")
    result = batch("shoot/*/*.mcap", "--out", out, "--formats", "pc2", cwd=tmp_path)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert f"Error: {out / 'day1'}: exists in the output folder {out} and is not a folder" in (
        result.stderr)
    assert (out / "day1").read_text() == "not a folder"
