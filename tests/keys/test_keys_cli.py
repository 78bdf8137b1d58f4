"""``puppet keys`` on the real dynamixel_sdk against hw_sim: keys captured with Enter on stdin
are the held poses exactly (the median of the hold window), replace / delete / insert change
the shot, a key while a servo is silent is refused naming it, and ``keys retime`` / ``keys
delete`` write a new shot by the output rule; the shot plays and exports like a take."""

import queue
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

import hw_sim
from puppet.rig import builtin
from puppet.rig.load import BUILTIN_RIG
from puppet.take import Playback, TakeReader

PUPPET = Path(sys.executable).with_name("puppet")


def pose(rig, degrees: dict[int, float]) -> dict[int, int]:
    """Shaft ticks of every servo for joint angles in degrees (servo id -> angle)."""
    ids = [int(i) for i in rig.servo_map.ids]
    ticks = rig.servo_map.ticks_for(np.radians([degrees.get(i, 0.0) for i in ids]))
    return dict(zip(ids, ticks.tolist()))


class Lines:
    """Lines of a pipe, collected by a thread; ``wait(text)`` waits for a line holding it."""

    def __init__(self, pipe, wait_until):
        self.wait_until = wait_until
        self.lines: list[str] = []
        self._queue: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, args=(pipe,), daemon=True).start()

    def _read(self, pipe):
        for line in pipe:
            self.lines.append(line.rstrip("\n"))

    def wait(self, text: str, start: int = 0) -> int:
        """Index of the first line from ``start`` on holding ``text`` (waits for it)."""
        def found():
            for i, line in enumerate(self.lines[start:], start):
                if text in line:
                    return i + 1
            return 0
        return self.wait_until(found, what=f"a line with {text!r}; got {self.lines}") - 1


def run(*args):
    return subprocess.run([str(PUPPET), *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def test_keys_captured_with_enter_edited_and_retimed(tmp_path, wait_until, interrupt_and_wait):
    rig = builtin()
    shot = tmp_path / "shot.mcap"
    poses = [pose(rig, {}), pose(rig, {4: -60, 5: 40, 1: 20}), pose(rig, {10: -50, 12: 70}),
             pose(rig, {7: 60, 8: -30, 2: -40}), pose(rig, {13: -30, 15: 50}),
             pose(rig, {6: -45, 9: 45})]
    with hw_sim.serve(rig.servo_map.models) as bus:
        bus.set_positions(poses[0])
        proc = subprocess.Popen([str(PUPPET), "keys", "--rig", str(BUILTIN_RIG), "--port",
                                 bus.port, "--out", str(shot), "--fps", "24", "--step", "12"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, bufsize=1)
        out, err = Lines(proc.stdout, wait_until), Lines(proc.stderr, wait_until)
        try:
            out.wait("press Enter")

            def command(line, expect, stream=out):
                start = len(stream.lines)
                proc.stdin.write(line + "\n")
                proc.stdin.flush()
                wait_until(lambda: any(expect in x for x in stream.lines[start:]),
                           what=f"{expect!r} after {line!r}; out {out.lines}, err {err.lines}")
                return stream.lines[stream.wait(expect, start)]

            def taken(line, expect):
                """Send a pose command until it is taken: a key refused because a read failed
                on this busy machine (said on stderr) is pressed again, as a puppeteer would."""
                def answer():
                    start_out, start_err = len(out.lines), len(err.lines)
                    proc.stdin.write(line + "\n")
                    proc.stdin.flush()
                    wait_until(lambda: any(expect in x for x in out.lines[start_out:])
                               or any("refused" in x for x in err.lines[start_err:]),
                               what=f"an answer to {line!r}; out {out.lines}, err {err.lines}")
                    return next((x for x in out.lines[start_out:] if expect in x), None)
                return wait_until(answer, what=f"{line!r} taken; err {err.lines}")

            for i in range(5):
                bus.set_positions(poses[i])
                assert taken("", f"key {i}:").startswith(f"key {i}: frame {1 + 12 * i} (")
            bus.inject("drop", [3])  # servo 3 silent: a key now is refused, naming it

            def refused_naming_3():
                answer = command("", "refused", err)
                assert not any(f"key 5" in line for line in out.lines)  # never taken
                return "servo(s) [3] flagged" in answer
            wait_until(refused_naming_3, what="a refusal naming servo 3 once the reader finds it")
            bus.clear_faults()
            bus.set_positions(poses[5])

            taken("r 2", "key 2: replaced")  # once servo 3 answers again
            assert command("d 3", "deleted") == "key 3: deleted (4 keys left)"
            bus.set_positions(poses[3])
            # ids are stable: key 3 is gone, the inserted key is the next unused id, 5
            assert taken("i 30", "inserted").startswith("key 5: inserted at frame 30")
            proc.stdin.write("q\n")
            proc.stdin.flush()
            assert proc.wait(timeout=120) == 0
        finally:
            if proc.poll() is None:
                interrupt_and_wait(proc, read_stderr=False)
    assert "keys: 5, 49 frames at 24 fps" in "\n".join(out.lines)
    reader = TakeReader(shot)
    keys = reader.keys()
    assert [k.frame for k in keys.keys] == [1, 13, 25, 30, 49]
    ids = [int(i) for i in rig.servo_map.ids]
    held = [poses[0], poses[1], poses[5], poses[3], poses[4]]
    for key, expected in zip(keys.keys, held):
        assert key.ticks.tolist() == [expected[i] for i in ids] and key.ok.all()
    frames = Playback.of_take(reader, ids, fps=24, rig=rig)
    assert len(frames) == 49  # the last key's frame

    # retime two keys into a new shot; the input is never written
    before = shot.read_bytes()
    retimed = tmp_path / "retimed.mcap"
    result = run("keys", "retime", shot, "5=40", "4=52", "--out", retimed)
    assert result.returncode == 0, result.stderr
    assert [k.frame for k in TakeReader(retimed).keys().keys] == [1, 13, 25, 40, 52]
    bad = run("keys", "retime", shot, "5=20", "--out", tmp_path / "bad.mcap")
    assert bad.returncode == 1 and "Traceback" not in bad.stderr
    assert "key 5 (frame 20) would land before key 2 (frame 25)" in bad.stderr
    same = run("keys", "retime", shot, "5=40", "--out", shot)
    assert same.returncode == 1 and str(shot) in same.stderr and "Traceback" not in same.stderr
    gone = run("keys", "delete", retimed, "1", "--out", tmp_path / "fewer.mcap")
    assert gone.returncode == 0, gone.stderr
    assert [k.frame for k in TakeReader(tmp_path / "fewer.mcap").keys().keys] == [1, 25, 40, 52]
    smooth = tmp_path / "smooth.mcap"
    chosen = run("keys", "interpolation", retimed, "0=smooth", "2=step", "--out", smooth)
    assert chosen.returncode == 0, chosen.stderr
    assert [k.interpolation for k in TakeReader(smooth).keys().keys] == [
        "smooth", "linear", "step", "linear", "linear"]
    wrong = run("keys", "interpolation", retimed, "1=cubic", "--out", tmp_path / "no.mcap")
    assert wrong.returncode == 1 and "interpolation 'cubic' is not one of linear, smooth, step" in wrong.stderr
    assert not (tmp_path / "no.mcap").exists()
    assert shot.read_bytes() == before

    # the shot exports like any take: one BVH frame per shot frame
    bvh = tmp_path / "shot.bvh"
    exported = run("export", retimed, "--fps", "24", "--bvh", bvh)
    assert exported.returncode == 0, exported.stderr
    assert "Frames: 52" in bvh.read_text()


def test_ctrl_c_ends_a_capture_with_every_key_kept(tmp_path, wait_until, interrupt_and_wait):
    rig = builtin()
    shot = tmp_path / "shot.mcap"
    with hw_sim.serve(rig.servo_map.models) as bus:
        bus.set_positions(pose(rig, {4: 30}))
        proc = subprocess.Popen([str(PUPPET), "keys", "--rig", str(BUILTIN_RIG), "--port",
                                 bus.port, "--out", str(shot), "--step", "8"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, bufsize=1)
        out, err = Lines(proc.stdout, wait_until), Lines(proc.stderr, wait_until)
        try:
            out.wait("press Enter")

            def one_key():
                proc.stdin.write("\n")
                proc.stdin.flush()
                start = len(err.lines)
                wait_until(lambda: any("key 0:" in x for x in out.lines)
                           or any("refused" in x for x in err.lines[start:]), what="an answer")
                return any("key 0:" in x for x in out.lines)
            wait_until(one_key, what=f"key 0 taken; err {err.lines}")
        finally:
            code = interrupt_and_wait(proc, read_stderr=False)
    assert code == 0, err.lines
    assert "keys: 1, 1 frames at 24 fps" in "\n".join(out.lines)
    keys = TakeReader(shot).keys()
    assert [k.frame for k in keys.keys] == [1]
    assert keys.keys[0].ticks.tolist() == [pose(rig, {4: 30})[int(i)] for i in rig.servo_map.ids]
