"""puppet session: the session folder from a terminal (a few end-to-end cases; the contract
itself is tested in-process in test_session_folder.py)."""

import json
import subprocess

from puppet.studio import SessionWriter


def run(*args):
    return subprocess.run(["puppet", "session", *map(str, args)], capture_output=True,
                          text=True, timeout=120)


def test_session_commands(tmp_path, kit):
    folder = tmp_path / "shoot"
    made = run("shot", folder, "walk")
    assert made.returncode == 0, made.stderr
    with SessionWriter.open(folder) as session:  # a recording (the studio's part)
        kit.record(session)
        kit.record(session)
    for args in (("circle", "walk", 2), ("note", "walk", 2, "keep this one"),
                 ("lock", "walk", 2), ("delete", "walk", 1), ("restore", "walk", 1),
                 ("segment", "walk", 1, "step", 0.25, 0.5, "--loop"),
                 ("rename", "walk", "walk, final")):
        result = run(args[0], folder, *args[1:])
        assert result.returncode == 0, (args, result.stderr)
    refused = run("delete", folder, "walk", 2)
    assert refused.returncode == 1 and "Traceback" not in refused.stderr
    assert "Error: " in refused.stderr and "take 2 is locked (read-only): cannot delete it" in \
        refused.stderr
    bad = run("circle", folder, "walk", 0)
    assert bad.returncode == 2 and "must be an integer 1..10000" in bad.stderr
    table = run("list", folder)
    assert table.returncode == 0, table.stderr
    assert "shot 'walk, final' [takes/walk/]  (current)" in table.stdout
    assert "circled locked  note: 'keep this one'" in table.stdout
    listing = json.loads(run("list", folder, "--json").stdout)
    takes = listing["shots"][0]["takes"]
    assert [(t["number"], t["circled"], t["locked"], t["trashed"], t["status"]) for t in takes] \
        == [(1, False, False, False, "ok"), (2, True, True, False, "ok")]
    assert takes[0]["segments"] == [{"name": "step", "in_s": 0.25, "out_s": 0.5, "loop": True}]
