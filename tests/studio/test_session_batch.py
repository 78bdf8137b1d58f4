"""puppet batch SESSION --circled: the session folder the studio writes is the batch's input;
outputs land in its exports/ folder, mirroring its shots, equal to puppet export's."""

import json
import subprocess

import pytest

from puppet.studio import SessionWriter


def run(*args):
    return subprocess.run(["puppet", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


@pytest.fixture(scope="module")
def critter():
    from puppet.rig import builtin

    return builtin()


@pytest.fixture
def shoot(tmp_path, kit, critter):
    """A session of two shots and five takes of the critter: walk 1, walk 2 (circled),
    walk 3 (circled, then deleted), jump 1 (circled), jump 2 (circled, then its file removed
    behind the studio's back)."""
    servo_map = critter.servo_map
    rig = dict(ids=[int(i) for i in servo_map.ids], models=dict(servo_map.models),
               zero=servo_map.zero, rig_name=critter.name, readings=10)
    folder = tmp_path / "shoot"
    with SessionWriter.open(folder) as session:
        session.new_shot("walk")
        for seed in range(3):
            kit.record(session, seed=seed, **rig)
        session.new_shot("jump")
        for seed in range(2):
            kit.record(session, seed=seed + 5, **rig)
        for shot, number in (("walk", 2), ("walk", 3), ("jump", 1), ("jump", 2)):
            session.circle(shot, number)
        session.delete("walk", 3)
    (folder / "takes" / "jump" / "take002.mcap").unlink()
    return folder


def test_batch_circled_exports_into_the_session(shoot, tmp_path):
    result = run("batch", shoot, "--circled", "--formats", "gltf", "--workers", 1)
    assert result.returncode == 0, result.stderr
    assert "take002.mcap: shot 'jump' take 2 is missing" in result.stderr  # said, skipped
    made = sorted(str(p.relative_to(shoot / "exports"))
                  for p in (shoot / "exports").rglob("*.glb"))
    assert made == ["jump/take001.glb", "walk/take002.glb"]
    for shot, number in (("walk", 2), ("jump", 1)):
        alone = tmp_path / f"{shot}.glb"
        exported = run("export", shoot / "takes" / shot / f"take00{number}.mcap", "--gltf", alone)
        assert exported.returncode == 0, exported.stderr
        assert (shoot / "exports" / shot / f"take00{number}.glb").read_bytes() == \
            alone.read_bytes()
    listing = json.loads(run("session", "list", shoot, "--json").stdout)
    rows = {(s["name"], t["number"]): (t["status"], t["circled"])
            for s in listing["shots"] for t in s["takes"]}
    assert rows == {("walk", 1): ("ok", False), ("walk", 2): ("ok", True),
                    ("walk", 3): ("trashed", True), ("jump", 1): ("ok", True),
                    ("jump", 2): ("missing", True)}


def test_batch_of_a_session_plans_its_takes(shoot, tmp_path):
    """Without --circled: every take outside the trash; --out is still honoured."""
    result = run("batch", shoot, "--formats", "gltf", "--dry-run", "--json", "--out",
                 tmp_path / "elsewhere")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["out"] == str(tmp_path / "elsewhere")
    assert [row["take"] for row in report["takes"]] == [
        str(shoot / "takes" / shot / f"take00{n}.mcap")
        for shot, n in (("walk", 1), ("walk", 2), ("jump", 1))]
    assert not (tmp_path / "elsewhere").exists()


def test_batch_session_bad_input(shoot, tmp_path, kit):
    take = shoot / "takes" / "walk" / "take001.mcap"
    result = run("batch", take, "--circled", "--formats", "gltf")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert f"Error: --circled: picks a session folder's circled takes; {take} is not" in \
        result.stderr
    result = run("batch", take, "--formats", "gltf")
    assert result.returncode == 1 and "Error: --out: missing" in result.stderr
    result = run("batch", shoot, take, "--formats", "gltf")
    assert result.returncode == 1 and "a session folder is batched alone" in result.stderr
    with SessionWriter.open(tmp_path / "plain") as session:
        kit.record(session)
    result = run("batch", tmp_path / "plain", "--circled", "--formats", "gltf")
    assert result.returncode == 1
    assert f"Error: {tmp_path / 'plain'}: no circled takes to batch" in result.stderr
    assert not any((tmp_path / "plain" / "exports").iterdir())


def test_batch_of_a_24_fps_session_exports_at_24_unless_told(tmp_path, kit, critter):
    """Takes recorded at 24 fps (``puppet studio --fps 24``: their start timecode's rate)
    export at 24 from ``puppet batch SESSION``, as from the page; --fps says otherwise; takes
    of two rates (or none) export at the default 30."""
    import pygltflib

    from puppet.timecode import StartTimecode

    servo_map = critter.servo_map
    rig = dict(ids=[int(i) for i in servo_map.ids], models=dict(servo_map.models),
               zero=servo_map.zero, rig_name=critter.name, readings=13)
    folder = tmp_path / "shoot"
    with SessionWriter.open(folder) as session:
        session.new_shot("walk")
        kit.record(session, timecode=StartTimecode("01:00:00:00", "24"), **rig)
        session.circle("walk", 1)

    def fps_of(glb):
        return pygltflib.GLTF2().load_binary(str(glb)).scenes[0].extras["puppet_fps"]

    glb = folder / "exports" / "walk" / "take001.glb"
    result = run("batch", folder, "--circled", "--formats", "gltf", "--workers", 1)
    assert result.returncode == 0, result.stderr
    assert fps_of(glb) == 24.0
    result = run("batch", folder, "--circled", "--formats", "gltf", "--workers", 1, "--fps", 30)
    assert result.returncode == 0, result.stderr
    assert fps_of(glb) == 30.0

    with SessionWriter.open(folder) as session:
        kit.record(session, timecode=StartTimecode("01:00:00:00", "25"), **rig)
        session.circle("walk", 2)
    result = run("batch", folder, "--circled", "--formats", "gltf", "--workers", 1)
    assert result.returncode == 0, result.stderr
    assert fps_of(glb) == fps_of(folder / "exports" / "walk" / "take002.glb") == 30.0
