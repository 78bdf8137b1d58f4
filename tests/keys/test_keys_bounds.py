"""Shots stay bounded and edits stay on the key meant: a key past the shot's documented length
(``puppet.limits.SHOT_SECONDS``) is refused naming it; every export refuses, before writing, a
file over ``puppet.limits.EXPORT_BYTES`` unless forced (the estimate is exact for PC2); keys are
addressed by a stable id, so a skipped damaged key renumbers nothing, and it stays in the edited
file; ``q`` ends a capture whose command queue is full; a capture with no key writes nothing."""

import json
import time

import pytest

from puppet import limits
from puppet.export import ExportError, Outputs, export_take
from puppet.keys import read_shot, retime, write_shot
from puppet.keys.capture import WAITING_COMMANDS, KeyDesk, KeyRefused, KeySession
from puppet.keys.example import critter_keys
from puppet.rig import builtin
from puppet.take import TakeError, TakeReader
from puppet.take.keys import Key, last_frame


@pytest.fixture(scope="module")
def critter():
    return builtin()


def header_of(rig):
    return {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
            "rig_map_text": "", "calibration_text": "", "rig_name": rig.name}


def test_a_key_past_the_shots_length_is_refused_naming_it(tmp_path, critter):
    keys = critter_keys(critter, step=12, fps=24)
    assert last_frame(24) == 1 + int(limits.SHOT_SECONDS.hi * 24)
    with pytest.raises(TakeError) as err:
        retime(keys, {3: 10_000_000}, "shot.mcap")
    message = str(err.value)
    assert message.startswith("shot.mcap: key 3: frame 10000000 is not within 1..86401")
    assert "SHOT_SECONDS" in message and "3600 s" in message
    assert [k.frame for k in retime(keys, {3: last_frame(24)}).keys][-1] == 86401  # the bound
    with pytest.raises(TakeError, match="key 3: frame 86402"):
        write_shot(tmp_path / "long.mcap", header_of(critter),
                   type(keys)(24.0, keys.keys[:3] + [Key(86402, keys.keys[3].ticks,
                                                         keys.keys[3].ok, id=3)]))
    assert not (tmp_path / "long.mcap").exists()


def test_an_export_over_the_size_limit_is_refused_before_writing_unless_forced(
        tmp_path, critter, monkeypatch):
    from puppet.export.run import estimated_bytes
    from puppet.replay import open_take

    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), critter_keys(critter, step=12, fps=24))
    rig, reader = open_take(shot, critter)
    pc2 = tmp_path / "shot.pc2"
    report = export_take(rig, reader, Outputs(pc2=pc2), fps=24)
    size = pc2.stat().st_size
    assert size == estimated_bytes("pc2", report.frames, len(critter.V) if critter.source_index
                                   is None else len(critter.source_index),
                                   critter.skeleton.bone_count)
    pc2.unlink()
    monkeypatch.setattr(limits, "EXPORT_BYTES", limits.Range(0, size - 40, "bytes", integer=True))
    for fmt in ("pc2", "usd"):
        target = tmp_path / f"big.{'pc2' if fmt == 'pc2' else 'usdc'}"
        with pytest.raises(ExportError, match=rf"the --{fmt} output would be about .* over the "
                                              r".* without --force \(puppet.limits.EXPORT_BYTES\)"):
            export_take(rig, reader, Outputs(**{fmt: target}), fps=24)
        assert not target.exists()
    export_take(rig, reader, Outputs(pc2=pc2, force=True), fps=24)
    assert pc2.stat().st_size == size


def _damage_key(shot, index: int) -> bytes:
    """Make key ``index``'s message fail its checksum (it now claims index 7); its bytes."""
    data = bytearray(shot.read_bytes())
    marker = json.dumps({"index": index}).encode()[1:-1]
    at = data.find(marker)
    assert at > 0
    data[at + len(marker) - 1] = ord("7")
    shot.write_bytes(bytes(data))
    start = data.rfind(b"{", 0, at)
    return bytes(data[start:data.find(b"}", at) + 1])


def test_edits_address_keys_by_id_and_keep_a_damaged_key(tmp_path, critter):
    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), critter_keys(critter, step=12, fps=24))
    damaged = _damage_key(shot, 0)  # the first key: every later place shifts
    header, keys, reader = read_shot(shot)
    assert [(k.id, k.frame) for k in keys.keys] == [(1, 13), (2, 25), (3, 37)]
    moved = retime(keys, {1: 5})  # key 1 (frame 13), not the key now in place 1 (key 2)
    assert [(k.id, k.frame) for k in moved.keys] == [(1, 5), (2, 25), (3, 37)]
    out = tmp_path / "moved.mcap"
    write_shot(out, header, moved)
    assert damaged in out.read_bytes()  # the damaged key stays in the output file
    again = TakeReader(out)
    assert [(k.id, k.frame) for k in again.keys().keys] == [(1, 5), (2, 25), (3, 37)]
    assert "skipped 1 damaged key(s)" in again.recovery



def test_q_and_end_of_input_end_a_capture_whose_queue_is_full(tmp_path, critter):
    path = tmp_path / "never.mcap"
    session = KeySession(path, header_of(critter), fps=24, step=12)
    said = []
    desk = KeyDesk(session, tell=lambda origin, taken, words: said.append((taken, words)))
    for _ in range(WAITING_COMMANDS):
        desk.press("")  # keys waiting for readings that never come
    with pytest.raises(KeyRefused, match="commands wait already"):
        desk.press("")
    desk.press("q")  # never refused
    deadline = time.monotonic() + 120  # generous: QUIT_WAIT_NS after q, however loaded
    while not desk.finished and time.monotonic() < deadline:
        desk.step()
        time.sleep(0.01)
    assert desk.finished
    assert len(said) == WAITING_COMMANDS and not any(taken for taken, _ in said)
    assert "q ended the capture before its hold window" in said[0][1]
    assert not session.written and not path.exists()


def test_a_capture_with_no_key_writes_nothing(tmp_path, critter):
    path = tmp_path / "none.mcap"
    session = KeySession(path, header_of(critter), fps=24, step=12)
    desk = KeyDesk(session)
    desk.press("m smooth")  # a setting, not a key
    desk.press("q")
    desk.step()
    assert desk.finished and session.interpolation == "smooth"
    assert not session.written and not path.exists()


def test_play_refuses_a_video_over_the_size_limit_before_writing(tmp_path, critter):
    import subprocess

    from puppet.cli.play import _check_size
    from puppet.export.run import estimated_bytes
    from puppet.replay import PLAY_SIZE

    keys = critter_keys(critter, step=12, fps=24)
    last = keys.keys[-1]
    long_keys = type(keys)(24.0, keys.keys[:-1] + [Key(24 * 600, last.ticks, last.ok, id=last.id)])
    shot = tmp_path / "long.mcap"
    write_shot(shot, header_of(critter), long_keys)  # ten minutes: at 1000 fps, 600 000 frames
    video = tmp_path / "long.mp4"
    done = subprocess.run(["puppet", "play", str(shot), "--out", str(video), "--fps", "1000"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr
    assert done.stderr.startswith(f"Error: {video}: the --out video would be about "), done.stderr
    assert "640x480 at 1000 fps" in done.stderr and "puppet.limits.EXPORT_BYTES" in done.stderr
    assert "Traceback" not in done.stderr and not video.exists()
    assert list(tmp_path.iterdir()) == [shot]  # no partial file either
    frames = 600_000

    def check(frames, fps, force):
        _check_size("mp4", str(video), "the --out video", frames, fps, force)

    assert estimated_bytes("mp4", frames, pixels=PLAY_SIZE[0] * PLAY_SIZE[1]) > limits.EXPORT_BYTES.hi
    check(frames, 1000.0, force=True)  # --force: past the rule
    with pytest.raises(ExportError, match="--out video"):
        check(frames, 1000.0, force=False)
    # a video within the limit is not refused: the shot at its own rate
    check(24 * 600, 24.0, force=False)


def test_play_refuses_png_frames_over_the_size_limit_before_writing(tmp_path, critter):
    """--frames FOLDER is under the export's size rule as --out is: refused before the folder
    is made, naming it; --force passes."""
    import subprocess

    from puppet.cli.play import _check_size
    from puppet.export.run import estimated_bytes
    from puppet.replay import PLAY_SIZE

    keys = critter_keys(critter, step=12, fps=24)
    last = keys.keys[-1]
    long_keys = type(keys)(24.0, keys.keys[:-1] + [Key(24 * 600, last.ticks, last.ok, id=last.id)])
    shot = tmp_path / "long.mcap"
    write_shot(shot, header_of(critter), long_keys)  # ten minutes: at 1000 fps, 600 000 frames
    folder = tmp_path / "frames"
    done = subprocess.run(["puppet", "play", str(shot), "--frames", str(folder), "--fps", "1000"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr
    assert done.stderr.startswith(f"Error: {folder}: the --frames PNGs would be about "), done.stderr
    assert "640x480 at 1000 fps" in done.stderr and "puppet.limits.EXPORT_BYTES" in done.stderr
    assert "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == [shot]  # not even the folder
    frames = 600_000

    def check_frames(frames, fps, force):
        _check_size("png", str(folder), "the --frames PNGs", frames, fps, force)

    assert estimated_bytes("png", frames, pixels=PLAY_SIZE[0] * PLAY_SIZE[1]) > limits.EXPORT_BYTES.hi
    check_frames(frames, 1000.0, force=True)  # --force: past the rule
    with pytest.raises(ExportError, match="--frames PNGs"):
        check_frames(frames, 1000.0, force=False)
    check_frames(24 * 600, 24.0, force=False)  # the shot at its own rate


def test_a_key_given_twice_is_refused_and_a_cut_shot_says_where(tmp_path, critter):
    from click.testing import CliRunner

    from puppet.cli import main

    shot = tmp_path / "shot.mcap"
    write_shot(shot, header_of(critter), critter_keys(critter, step=12, fps=24))
    out = tmp_path / "out.mcap"
    twice = CliRunner().invoke(main, ["keys", "retime", str(shot), "1=5", "1=6", "--out", str(out)])
    assert twice.exit_code == 2 and "key 1 given twice ('1=5' and '1=6')" in twice.output, twice.output
    assert not out.exists()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(shot.read_bytes()[:3000])  # ends inside the keys
    done = CliRunner().invoke(main, ["keys", "retime", str(cut), "1=5", "--out", str(out)])
    assert done.exit_code == 0, done.output
    said = next(line for line in done.output.splitlines() if "ends damaged after" in line)
    assert "()" not in said, said  # the reason is named, never empty
