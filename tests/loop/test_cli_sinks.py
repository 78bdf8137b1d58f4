"""Videos written by the commands survive what users do to them: an encoder that dies mid-run
is an error (exit 1, the take intact), SIGTERM finishes the video as Ctrl-C does."""

import os
import signal
import subprocess
import time
from pathlib import Path

import imageio_ffmpeg
import numpy as np

import hw_sim
from puppet.bus import Reading
from puppet.rig import builtin
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader, TakeWriter


def wait_for(condition, timeout_s: float = 60.0, what: str = "the condition"):
    """Poll ``condition()`` until it returns something truthy (returned), or fail after timeout_s."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def encoder_of(pid: int) -> int | None:
    """The pid of the ffmpeg process that ``pid`` started to encode a video, or None yet."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        parent = int(stat.rsplit(")", 1)[1].split()[1])
        if parent == pid and b"rawvideo" in cmdline:
            return int(entry.name)
    return None


def partial_files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".partial" in p.name)


def test_encoder_killed_mid_run_stops_live_with_an_error_and_keeps_the_take(tmp_path):
    take, video = tmp_path / "live.mcap", tmp_path / "live.mp4"
    rig = builtin()
    with hw_sim.serve(rig.servo_map.models, motion="wave") as bus:
        proc = subprocess.Popen(["puppet", "live", "--rig", str(BUILTIN_RIG), "--port", bus.port,
                                 "--record", str(take), "--out", str(video)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            encoder = wait_for(lambda: encoder_of(proc.pid), what="the video encoder to start")
            wait_for(lambda: take.exists() and take.stat().st_size > 20_000, what="readings in the take")
            os.kill(encoder, signal.SIGKILL)  # as the OOM killer or a full disk would end it
            stdout, stderr = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 1, stderr
    assert "Error:" in stderr and str(video) in stderr and "video encoder" in stderr
    assert "Traceback" not in stderr
    assert not video.exists()  # no unplayable half video
    assert partial_files(tmp_path) == []
    reader = TakeReader(take)  # the take is whole: every reading readable, none truncated
    assert not reader.truncated
    assert len(reader) > 50
    assert len(list(reader.readings())) == len(reader)


def _long_take(path: Path, seconds: float) -> Path:
    rig = builtin()
    k = len(rig.servo_map)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
        for i in range(int(seconds * 100)):
            ticks = (rig.servo_map.zero + 400 * np.sin(0.05 * i + np.arange(k))).astype(np.int32)
            writer.write(Reading(i * 10_000_000, rig.servo_map.ids, ticks, np.ones(k, bool)))
    return path


def test_sigterm_during_play_finishes_a_playable_video(tmp_path):
    take = _long_take(tmp_path / "long.mcap", seconds=120.0)  # 3600 frames: far longer than the wait
    video = tmp_path / "long.mp4"
    proc = subprocess.Popen(["puppet", "play", str(take), "--out", str(video), "--antialias", "none",
                             "--fps", "30"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # The encoder has its first frame: ffmpeg writes its temporary file's header once the
        # first frame reaches it.
        wait_for(lambda: any(p.stat().st_size > 0 for p in tmp_path.glob(".long.*.partial.mp4")),
                 what="a frame in the encoder's temporary video")
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    assert "stopped by SIGTERM" in stderr
    assert "Traceback" not in stderr
    assert partial_files(tmp_path) == []
    frames, _ = imageio_ffmpeg.count_frames_and_secs(str(video))  # playable: ffmpeg reads its index
    assert frames >= 1
    done = int(stdout.split("frames ", 1)[1].split()[0])
    assert frames == done < 3600
