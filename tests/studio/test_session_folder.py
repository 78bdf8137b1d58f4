"""The session folder's contract: plain files, take N numbering, marks, lock, trash, rename,
segments, and what happens when files change behind the studio's back."""

import json
import os
import time

import pytest

from puppet import limits
from puppet.studio import (IndexTooNew, SessionFolder, SessionWriter, StudioError, TakeLocked,
                           is_session)
from puppet.take import TakeReader


def index_of(folder):
    return json.loads((folder / "session.json").read_text(encoding="utf-8"))


def test_a_new_folder_is_made_with_its_layout(tmp_path):
    folder = tmp_path / "new" / "shoot"
    with SessionWriter.open(folder) as session:
        assert session.notes == []
        assert sorted(p.name for p in folder.iterdir()) == [
            "exports", "session.json", "session.lock", "takes", "trash"]
        assert is_session(folder)
        data = index_of(folder)
        assert (data["format"], data["version"], data["shots"]) == ("puppet session", 1, [])
    assert (folder / "session.lock").read_text() == ""  # let go: nobody holds it


def test_takes_are_numbered_per_shot_with_their_facts(tmp_path, kit):
    folder = tmp_path / "shoot"
    with SessionWriter.open(folder) as session:
        session.new_shot("Walk, slow")
        first = kit.record(session, readings=31)
        second = kit.record(session, readings=16, rig_name="critter")
        session.new_shot("jump")
        other = kit.record(session, readings=7)
    assert (first.number, second.number, other.number) == (1, 2, 1)
    assert (folder / "takes" / "Walk-slow" / "take001.mcap").is_file()
    assert (folder / "takes" / "Walk-slow" / "take002.mcap").is_file()
    assert (folder / "takes" / "jump" / "take001.mcap").is_file()
    assert first.duration_s == pytest.approx(30 / 30.0)
    assert second.duration_s == pytest.approx(15 / 30.0)
    assert (first.rig, second.rig, first.readings, second.readings) == (
        "bench", "critter", 31, 16)
    created = TakeReader(folder / first.file).metadata.created_unix_ns
    assert first.date == time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(created / 1e9))
    data = index_of(folder)  # what a person (or another program) reads
    assert [s["name"] for s in data["shots"]] == ["Walk, slow", "jump"]
    assert data["current_shot"] == "jump"
    assert [t["file"] for t in data["shots"][0]["takes"]] == [
        "takes/Walk-slow/take001.mcap", "takes/Walk-slow/take002.mcap"]
    again = SessionFolder.read(folder)  # a reader sees what the writer wrote
    assert again.notes == []
    assert [(s.name, [t.number for t in s.takes]) for s in again.index.shots] == [
        ("Walk, slow", [1, 2]), ("jump", [1])]


def test_a_first_recording_makes_a_first_shot(tmp_path, kit):
    with SessionWriter.open(tmp_path / "s") as session:
        take = kit.record(session)
        assert (session.current_shot.name, take.number) == ("shot 1", 1)


def test_circle_note_and_lock(tmp_path, kit):
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        session.new_shot("walk")
        kit.record(session)
        kit.record(session)
        session.circle("walk", 2)
        session.note("walk", 2, "nice arc on the tail\nkeep")
        session.lock_take("walk", 2)
        for action in (lambda: session.note("walk", 2, "x"),
                       lambda: session.circle("walk", 2, False),
                       lambda: session.add_segment("walk", 2, "a", 0.1, 0.5),
                       lambda: session.delete("walk", 2)):
            with pytest.raises(TakeLocked) as refused:
                action()
            assert "shot 'walk' take 2 is locked (read-only)" in str(refused.value)
            assert str(folder) in str(refused.value)
        assert (folder / "takes" / "walk" / "take002.mcap").is_file()  # never moved
        session.lock_take("walk", 2, locked=False)
        session.circle("walk", 2, False)
        session.circle("walk", 1)
    take1, take2 = index_of(folder)["shots"][0]["takes"]
    assert (take1["circled"], take2["circled"]) == (True, False)
    assert (take2["note"], take2["locked"]) == ("nice arc on the tail\nkeep", False)


def test_notes_and_names_are_bounded(tmp_path, kit):
    with SessionWriter.open(tmp_path / "s") as session:
        kit.record(session)
        with pytest.raises(StudioError, match=f"at most {limits.NOTE_CHARS} characters"):
            session.note("shot 1", 1, "x" * (limits.NOTE_CHARS + 1))
        with pytest.raises(StudioError, match="control character"):
            session.note("shot 1", 1, "bad\x00note")
        with pytest.raises(StudioError, match=f"at most {limits.NAME_CHARS} characters"):
            session.new_shot("n" * (limits.NAME_CHARS + 1))
        with pytest.raises(StudioError, match="must not be empty"):
            session.new_shot("  ")
        with pytest.raises(StudioError, match="no take 9"):
            session.circle("shot 1", 9)
        with pytest.raises(StudioError, match="no shot 'nope'"):
            session.circle("nope", 1)
        session.note("shot 1", 1, "y" * limits.NOTE_CHARS)


def test_delete_goes_to_the_trash_and_restore_brings_it_back(tmp_path, kit):
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        session.new_shot("walk")
        kit.record(session)
        kit.record(session)
        content = (folder / "takes/walk/take002.mcap").read_bytes()
        session.delete("walk", 2)
        assert not (folder / "takes/walk/take002.mcap").exists()
        assert (folder / "trash/walk/take002.mcap").read_bytes() == content
        shot, take = session.take("walk", 2)
        assert (take.trashed, session.status(shot, take)) == (True, "trashed")
        with pytest.raises(StudioError, match="in the trash: restore it first"):
            session.circle("walk", 2)
        third = kit.record(session)  # a trashed take keeps its number
        assert third.number == 3
        session.restore("walk", 2)
        assert (folder / "takes/walk/take002.mcap").read_bytes() == content
        assert not (folder / "trash/walk/take002.mcap").exists()
        with pytest.raises(StudioError, match="not in the trash"):
            session.restore("walk", 2)
    assert [t["trashed"] for t in index_of(folder)["shots"][0]["takes"]] == [False] * 3


def test_rename_a_shot_moves_no_file(tmp_path, kit):
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        session.new_shot("walk")
        kit.record(session)
        session.new_shot("run")
        session.rename_shot("walk", "walk, final")
        assert session.shot("walk").name == "walk, final"  # still found by its folder's name
        with pytest.raises(StudioError, match="a shot is called 'run' already"):
            session.rename_shot("walk, final", "RUN")
        session.use_shot("walk, final")
        assert kit.record(session).number == 2
    assert sorted(p.name for p in (folder / "takes" / "walk").iterdir()) == [
        "take001.mcap", "take002.mcap"]
    assert index_of(folder)["shots"][0]["name"] == "walk, final"


def test_segments(tmp_path, kit):
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        kit.record(session, readings=31)  # 1 s
        session.add_segment("shot 1", 1, "step", 0.25, 0.75, loop=True)
        session.add_segment("shot 1", 1, "all", 0, 1.0)
        with pytest.raises(StudioError, match="past the end"):
            session.add_segment("shot 1", 1, "long", 0.5, 1.5)
        with pytest.raises(StudioError, match="must come before the out point"):
            session.add_segment("shot 1", 1, "back", 0.5, 0.5)
        with pytest.raises(StudioError, match="has a segment 'step' already"):
            session.add_segment("shot 1", 1, "Step", 0.1, 0.2)
        session.remove_segment("shot 1", 1, "all")
        with pytest.raises(StudioError, match="no segment 'all'"):
            session.remove_segment("shot 1", 1, "all")
    assert index_of(folder)["shots"][0]["takes"][0]["segments"] == [
        {"name": "step", "in_s": 0.25, "out_s": 0.75, "loop": True}]


def test_a_take_removed_behind_the_studios_back_is_listed_missing(tmp_path, kit):
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        kit.record(session)
        kit.record(session)
        kit.record(session)
        session.circle("shot 1", 2)
        session.circle("shot 1", 3)
        (folder / "takes/shot-1/take002.mcap").unlink()
        shot, take = session.take("shot 1", 2)
        assert session.status(shot, take) == "missing"
        session.note("shot 1", 2, "gone?")  # its marks are the index's: still editable
    reader = SessionFolder.read(folder)
    rows = reader.listing()["shots"][0]["takes"]
    assert [r["status"] for r in rows] == ["ok", "missing", "ok"]
    chosen, missing = reader.chosen(circled=True)
    assert [take.number for _, take, _ in chosen] == [3]
    assert len(missing) == 1 and "take002.mcap" in missing[0] and "missing" in missing[0]
    assert "missing" in reader.table()
    with SessionWriter.open(folder) as session:  # opening again is no crash either
        assert [t.number for t in session.current_shot.takes] == [1, 2, 3]


def test_takes_found_on_disk_are_listed(tmp_path, kit):
    """A take the index does not list (recorded, then the studio killed before listing it;
    copied in by hand) is listed when the session is opened, and said."""
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        path = session.new_take_path()
        kit.write_take(path)  # recorded, never listed
    with SessionWriter.open(folder) as session:
        assert any("take001.mcap: found in takes/" in note for note in session.notes)
        assert session.take("shot 1", 1)[1].readings == 31


def test_a_layer_take_names_its_base(tmp_path, kit):
    """A layer take (recorded over take 1) is listed naming its base, in the index, in the
    listing and in the table; so after a rebuild, from takes/ and from the trash; an index
    written before the field existed reads as no layer."""
    from puppet.take.layers import LayerRef

    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        session.new_shot("walk")
        base = kit.record(session)
        path = session.new_take_path()
        kit.write_take(path, layer=LayerRef.over(folder / base.file, path, [3], rig_name="bench"))
        layer = session.add_take(path)
        plain = kit.record(session)
    assert (base.layer_over, layer.layer_over, plain.layer_over) == (
        None, "takes/walk/take001.mcap", None)
    assert [t["layer_over"] for t in index_of(folder)["shots"][0]["takes"]] == [
        None, "takes/walk/take001.mcap", None]
    reader = SessionFolder.read(folder)
    assert [t["layer_over"] for t in reader.listing()["shots"][0]["takes"]] == [
        None, "takes/walk/take001.mcap", None]
    assert "take   2" in reader.table() and "layer over take 1" in reader.table()
    assert reader.table().count("layer over") == 1

    with SessionWriter.open(folder) as session:
        session.delete("walk", 2)
    (folder / "session.json").unlink()
    with SessionWriter.open(folder) as session:  # rebuilt: the layer (in the trash) still names it
        assert session.take("walk", 2)[1].trashed
        assert session.take("walk", 2)[1].layer_over == "takes/walk/take001.mcap"
        assert session.take("walk", 3)[1].layer_over is None

    data = index_of(folder)
    for take in data["shots"][0]["takes"]:
        del take["layer_over"]  # an index from before the field
    (folder / "session.json").write_text(json.dumps(data))
    again = SessionFolder.read(folder)
    assert again.notes == [] and [t.layer_over for _, t in again.index.takes()] == [None] * 3


@pytest.mark.parametrize("damage", ["garbage", "bad field", "empty", "absent"])
def test_a_damaged_index_is_rebuilt_from_the_takes(tmp_path, kit, damage):
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        session.new_shot("walk")
        kit.record(session)
        kit.record(session, readings=16)
        session.circle("walk", 1)
        session.delete("walk", 2)
        session.new_shot("jump")
        kit.record(session)
    index = folder / "session.json"
    if damage == "garbage":
        index.write_bytes(b'{"format": "puppet session", "shots": [\x00\xff')
    elif damage == "bad field":
        data = index_of(folder)
        data["shots"][0]["takes"][0]["duration_s"] = "long"
        index.write_text(json.dumps(data))
    elif damage == "empty":
        index.write_bytes(b"")
    else:
        index.unlink()
    damaged = None if damage == "absent" else index.read_bytes()
    reader = SessionFolder.read(folder)  # reading rebuilds in memory, writes nothing
    assert "rebuilt from the 3 take(s)" in reader.notes[0]
    assert (index.read_bytes() if index.exists() else None) == damaged
    with SessionWriter.open(folder) as session:
        said = " ".join(session.notes)
        assert "rebuilt from the 3 take(s)" in said
        if damage == "bad field":
            assert "shots[0].takes[0].duration_s: must be a number" in said
        listed = [(s.key, t.number, t.trashed, t.readings) for s, t in session.index.takes()]
        assert listed == [("jump", 1, False, 31), ("walk", 1, False, 31), ("walk", 2, True, 16)]
        assert session.take("walk", 2)[1].duration_s == pytest.approx(0.5)
        kept = [p for p in (folder / "trash").iterdir() if p.name.startswith("session.damaged")]
        assert [p.read_bytes() for p in kept] == ([] if damaged is None else [damaged])
    assert index_of(folder)["format"] == "puppet session"  # written again, whole
    assert SessionFolder.read(folder).notes == []


def test_an_index_from_a_newer_puppet_is_never_rebuilt_over(tmp_path, kit):
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        kit.record(session)
    data = index_of(folder)
    data["version"] = 99
    (folder / "session.json").write_text(json.dumps(data))
    before = (folder / "session.json").read_bytes()
    with pytest.raises(IndexTooNew, match="newer puppet"):
        SessionWriter.open(folder)
    assert (folder / "session.json").read_bytes() == before


def test_a_folder_of_other_things_is_not_made_a_session(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "cat.jpg").write_bytes(b"\xff\xd8")
    with pytest.raises(StudioError, match="not a session folder"):
        SessionWriter.open(tmp_path / "photos")
    (tmp_path / "file").write_text("x")
    with pytest.raises(StudioError, match="is not a folder"):
        SessionWriter.open(tmp_path / "file")
    with pytest.raises(StudioError, match="not a session folder"):
        SessionFolder.read(tmp_path / "photos")
    assert sorted(p.name for p in (tmp_path / "photos").iterdir()) == ["cat.jpg"]


def test_only_paths_the_session_gave_are_added(tmp_path, kit):
    with SessionWriter.open(tmp_path / "s") as session:
        elsewhere = kit.write_take(tmp_path / "take001.mcap")
        session.new_take_path()
        with pytest.raises(StudioError, match="not a take path of session"):
            session.add_take(elsewhere)
        with pytest.raises(StudioError, match="no take file there"):
            session.add_take(session.new_take_path())


def test_a_closed_session_changes_nothing(tmp_path, kit):
    session = SessionWriter.open(tmp_path / "s")
    kit.record(session)
    session.close()
    with pytest.raises(StudioError, match="was closed"):
        session.circle("shot 1", 1)
    assert index_of(tmp_path / "s")["shots"][0]["takes"][0]["circled"] is False


def test_a_read_only_disk_fails_at_open_naming_the_folder(tmpfs, kit):
    disk = tmpfs.make("disk", "64m")
    folder = disk / "shoot"
    with SessionWriter.open(folder) as session:
        kit.record(session)
        session.circle("shot 1", 1)
    tmpfs.remount(disk, "ro")
    with pytest.raises(StudioError) as refused:
        SessionWriter.open(folder)
    assert str(folder) in str(refused.value) and "Read-only file system" in str(refused.value)
    with pytest.raises(StudioError, match="cannot create the session folder"):
        SessionWriter.open(disk / "new")
    reader = SessionFolder.read(folder)  # reading (batch, list) still works
    assert [t.circled for _, t in reader.index.takes()] == [True]


def test_a_full_disk_fails_before_recording_naming_the_folder(tmpfs, kit):
    disk = tmpfs.make("disk", "256k")
    with SessionWriter.open(disk / "shoot") as session:
        session.new_shot("walk")
        with pytest.raises(StudioError) as refused:
            session.new_take_path()
        assert str(disk / "shoot" / "takes" / "walk") in str(refused.value)
        assert "MiB free" in str(refused.value) and "SESSION_FREE_BYTES" in str(refused.value)
        filler = os.open(disk / "filler", os.O_WRONLY | os.O_CREAT)
        try:
            while True:
                os.write(filler, b"\0" * 4096)
        except OSError:
            pass
        finally:
            os.close(filler)
        with pytest.raises(StudioError, match="disk is full"):
            session.rename_shot("walk", "walk, a much longer name than the disk has room for")
        assert session.shot("walk").name == "walk"
    assert index_of(disk / "shoot")["shots"][0]["name"] == "walk"


def test_threads_of_one_studio_change_it_one_at_a_time(tmp_path, kit):
    """A page's handlers and a recording that ends may call the writer at once: every change
    is kept, the file is whole (they share one temporary file name: unserialised writes would
    rename each other's away)."""
    import threading

    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        kit.record(session)
        errors = []

        def work(n):
            try:
                for i in range(10):
                    session.new_shot(f"thread {n} shot {i}")
                    session.note("shot 1", 1, f"{n}.{i}")
            except Exception as err:  # noqa: BLE001 - reported by the assert below
                errors.append(err)

        threads = [threading.Thread(target=work, args=(n,)) for n in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=120)
        assert errors == []
    names = {s["name"] for s in index_of(folder)["shots"]}
    assert names == {"shot 1"} | {f"thread {n} shot {i}" for n in range(4) for i in range(10)}
