"""A terminal's Ctrl-C reaches the whole process group (the command, its bus reader, its video
encoder): `live`, `record`, `play` and `perform` stop cleanly (exit 0) and no process prints a
traceback. A run killed outright (SIGKILL) leaves its video, playable, under its own name."""

import os
import signal
import subprocess
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

import hw_sim
from puppet.bus import Reading
from puppet.rig import builtin
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeWriter
from tests.conftest import group_gone

PATIENCE_S = 60.0  # as tests/conftest.py: a generous wait, never a threshold


HOLD_TICKS = 2048
"""Where hw_sim's "hold" motion keeps every servo."""


def _take(path: Path, seconds: float, from_hold: bool = False) -> Path:
    """A take of the built-in rig: every servo swinging, 100 readings a second. from_hold: every
    servo starts at HOLD_TICKS (a puppet held there is at the take's first pose already)."""
    rig = builtin()
    k = len(rig.servo_map)
    centre, phase = (HOLD_TICKS, np.zeros(k)) if from_hold else (rig.servo_map.zero, np.arange(k))
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
        for i in range(int(seconds * 100)):
            ticks = (centre + 300 * np.sin(0.05 * i + phase)).astype(np.int32)
            writer.write(Reading(i * 10_000_000, rig.servo_map.ids, ticks, np.ones(k, bool)))
    return path


def _grown(pattern_folder: Path, pattern: str, size: int):
    """A predicate: some file matching ``pattern`` holds more than ``size`` bytes."""
    return lambda: any(p.stat().st_size > size for p in pattern_folder.glob(pattern)
                       if p.is_file())


def _encoding(folder: Path, pattern: str):
    """A predicate: the video's encoder has its first frame. The sink starts ffmpeg at the first
    frame and ffmpeg writes the header of its temporary file (``pattern``) once that frame
    reaches it."""
    return _grown(folder, pattern, 0)


def _command(name: str, tmp_path: Path, port: str):
    """(argv, predicate: the command is well under way)."""
    rig = ["--rig", str(BUILTIN_RIG), "--port", port]
    if name == "live":
        return (["live", *rig, "--record", str(tmp_path / "t.mcap"), "--out", str(tmp_path / "v.mp4")],
                _encoding(tmp_path, ".v.*.partial.mp4"))
    if name == "record":
        return ["record", *rig, "--out", str(tmp_path / "t.mcap")], _grown(tmp_path, "t.mcap", 20_000)
    take = _take(tmp_path / "long.mcap", 120.0, from_hold=name == "perform")
    if name == "play":
        return (["play", str(take), "--out", str(tmp_path / "v.mp4"), "--antialias", "none"],
                _encoding(tmp_path, ".v.*.partial.mp4"))
    err = tmp_path / "stderr.txt"
    return (["perform", str(take), "--port", port, "--yes", "--latency-ms", "20",
             "--watchdog-ms", "2000"], lambda: "phase: playback" in err.read_text())


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("name", ["perform"])  # the session's commands: tests/session/test_stop_contract.py
def test_one_ctrl_c_to_the_process_group_exits_0_without_a_traceback(name, sig, tmp_path,
                                                                     wait_until):
    """SIGINT as a terminal's Ctrl-C, SIGTERM as a service manager stopping the group. perform:
    the puppet held at the take's first pose (its slow move there is not what is tested)."""
    rig = builtin()
    with hw_sim.serve(dict(rig.servo_map.models), motion="hold" if name == "perform" else "wave") as bus:
        argv, under_way = _command(name, tmp_path, bus.port)
        err_path = tmp_path / "stderr.txt"
        with open(err_path, "w") as err:
            proc = subprocess.Popen(["puppet", *argv], stdout=subprocess.PIPE, stderr=err,
                                    text=True, process_group=0)  # a terminal's job
            try:
                wait_until(lambda: proc.poll() is not None or under_way(),
                           what=f"{name} under way")
                assert proc.poll() is None, err_path.read_text()
                os.killpg(proc.pid, sig)  # every process of the group
                proc.communicate(timeout=2 * PATIENCE_S)
            finally:
                if proc.poll() is None:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
    stderr = err_path.read_text()
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr, stderr
    assert "KeyboardInterrupt" not in stderr, stderr


def test_a_killed_live_run_leaves_its_video_under_its_name(tmp_path, wait_until):
    """SIGKILL of `live --out`: the encoder finishes the frames it was given and renames the
    video into place (README: Videos); no hidden partial file is left."""
    video = tmp_path / "x.mp4"
    rig = builtin()
    with hw_sim.serve(dict(rig.servo_map.models), motion="wave") as bus:
        proc = subprocess.Popen(["puppet", "live", "--rig", str(BUILTIN_RIG), "--port", bus.port,
                                 "--out", str(video)], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        try:
            wait_until(_encoding(tmp_path, ".x.*.partial.mp4"), what="a frame in the encoder")
            proc.kill()
            proc.wait()
            wait_until(lambda: video.exists(), what="the video renamed into place")
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    wait_until(lambda: not list(tmp_path.glob(".x.*")), what="no partial file left")
    frames, _ = imageio_ffmpeg.count_frames_and_secs(str(video))  # playable: it has its index
    assert frames >= 1


def test_ctrl_c_to_batch_leaves_no_worker_traceback(tmp_path, wait_until):
    """Batch workers are deaf to the terminal: the driver stops them; no traceback, no worker
    left running, no staging folder left."""
    takes = [_take(tmp_path / f"t{i}.mcap", 60.0) for i in range(2)]
    out = tmp_path / "out"
    err_path = tmp_path / "stderr.txt"
    with open(err_path, "w") as err:
        proc = subprocess.Popen(["puppet", "batch", *map(str, takes), "--out", str(out),
                                 "--formats", "pc2,bvh", "--workers", "2"],
                                stdout=subprocess.PIPE, stderr=err, text=True, process_group=0)
        try:
            wait_until(lambda: proc.poll() is not None
                       or any(p.is_dir() for p in out.glob(".puppet-batch.*.partial/*")),
                       what="a worker at work")
            assert proc.poll() is None, err_path.read_text()
            os.killpg(proc.pid, signal.SIGINT)
            proc.communicate(timeout=2 * PATIENCE_S)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    stderr = err_path.read_text()
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    wait_until(lambda: not list(out.glob(".puppet-batch.*")), what="the staging folder removed")
    wait_until(lambda: group_gone(proc.pid), what="every worker of the group ended")
