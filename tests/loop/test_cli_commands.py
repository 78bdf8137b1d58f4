"""The puppet commands end to end, as a user runs them (subprocesses, hw_sim as the bus)."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

import hw_sim
from puppet.bus import Reading
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeError, TakeReader, TakeWriter


def run(*args, timeout=300):
    return subprocess.run(["puppet", *map(str, args)], capture_output=True, text=True, timeout=timeout)


def assert_clean_error(result, *names):
    """A user-facing failure: exit 1, an 'Error:' line on stderr naming ``names``, no traceback."""
    assert result.returncode == 1, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("Error: ")]
    assert len(lines) == 1, result.stderr
    for name in names:
        assert str(name) in lines[0], (name, result.stderr)
    return lines[0]


def test_demo_writes_a_video_and_a_summary(tmp_path):
    out = tmp_path / "demo.mp4"
    result = run("demo", "--seconds", 2, "--out", out, "--json", "--size", 320, 240)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    # What the demo guarantees whatever the machine's speed (a loaded machine may render only a
    # frame or two in 2 s): it ran its time, solved and drew frames from bus readings, and the
    # video holds the run at 30 fps, a frame repeated while the loop was slower than that.
    assert summary["seconds"] >= 2.0
    assert 1 <= summary["frames"] <= summary["readings"]
    assert summary["fps"] > 0
    assert summary["latency_median_ms"] > 0
    assert summary["solver_us_per_iter"] > 0
    assert summary["dynamics"] is False
    frames, _ = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert 1 <= frames <= 30 * summary["seconds"] + 1
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = next(reader)
    assert tuple(meta["size"]) == (320, 240)


def test_demo_dynamics_runs_the_secondary_motion_variant(tmp_path):
    out = tmp_path / "dynamics.mp4"
    result = run("demo", "--dynamics", "--seconds", 1, "--out", out, "--json", "--size", 160, 120)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["dynamics"] is True
    assert summary["frames"] >= 1
    assert out.stat().st_size > 0


def test_record_killed_then_played_and_exported(tmp_path):
    take = tmp_path / "take.mcap"
    critter_ids = None
    with hw_sim.serve(_models(), motion="wave") as bus:
        proc = subprocess.Popen(["puppet", "record", "--rig", str(BUILTIN_RIG), "--port", bus.port,
                                 "--out", str(take), "--rate", "200"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 120

        def recorded():
            try:
                return len(TakeReader(take))
            except (OSError, TakeError):  # not there yet, or its header still on its way
                return 0

        while recorded() <= 100:
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "no 100 readings recorded within 120 s"
            time.sleep(0.1)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    reader = TakeReader(take)
    assert len(reader) > 100
    assert reader.metadata.rig_name == "critter"
    readings = list(reader.readings())
    # every servo was read (a loaded machine may flag a reading whose reply it still waits for)
    assert np.any([r.ok for r in readings], axis=0).all()
    ticks = np.stack([r.ticks for r in readings])
    assert ticks.std(axis=0).max() > 10  # the wave moved the servos

    video = tmp_path / "take.mp4"
    result = run("play", take, "--out", video, "--speed", 2.0)
    assert result.returncode == 0, result.stderr
    assert imageio_ffmpeg.count_frames_and_secs(str(video))[0] >= 1

    pc2, bvh = tmp_path / "mesh.pc2", tmp_path / "skeleton.bvh"
    result = run("export", take, "--pc2", pc2, "--bvh", bvh, "--fps", 10)
    assert result.returncode == 0, result.stderr
    header = pc2.read_bytes()[:32]
    assert header[:12] == b"POINTCACHE2\0"
    num_points, = np.frombuffer(header[16:20], np.int32)
    num_samples, = np.frombuffer(header[28:32], np.int32)
    from puppet.rig import builtin

    assert num_points == len(builtin().V)
    assert num_samples >= 1
    assert pc2.stat().st_size == 32 + 12 * num_points * num_samples
    text = bvh.read_text()
    assert text.startswith("HIERARCHY")
    assert f"Frames: {num_samples}" in text


def test_live_records_every_reading_and_writes_video(tmp_path):
    take, video = tmp_path / "live.mcap", tmp_path / "live.mp4"
    with hw_sim.serve(_models(), motion="wave") as bus:
        result = run("live", "--rig", BUILTIN_RIG, "--port", bus.link, "--seconds", 2,
                     "--record", take, "--out", video)
    assert result.returncode == 0, result.stderr
    readings = int(re.search(r"(\d+) readings", result.stdout).group(1))
    assert readings >= 1
    assert len(TakeReader(take)) == readings   # every reading the loop took is in the take
    assert imageio_ffmpeg.count_frames_and_secs(str(video))[0] >= 1


def test_play_is_deterministic(tmp_path):
    take = _synthetic_take(tmp_path / "t.mcap")
    caches = []
    for i in range(2):
        out = tmp_path / f"m{i}.pc2"
        result = run("export", take, "--pc2", out, "--fps", 20)
        assert result.returncode == 0, result.stderr
        caches.append(out.read_bytes())
    assert caches[0] == caches[1]


def test_scan_and_calibrate_on_the_simulated_bus(tmp_path):
    with hw_sim.serve({1: "XL330-M288", 2: "XL430-W250"}) as bus:
        result = run("scan", "--port", bus.port)
        assert result.returncode == 0, result.stderr
        assert "XL330-M288" in result.stdout and "XL430-W250" in result.stdout

    models = _models()
    with hw_sim.serve(models) as bus:
        bus.set_positions({i: 2000 + i for i in models})
        cal = tmp_path / "cal.toml"
        result = run("calibrate", "--rig", BUILTIN_RIG, "--port", bus.port, "--out", cal)
        assert result.returncode == 0, result.stderr
    from puppet.rig import Calibration

    assert Calibration.load(cal).zero_ticks == {i: 2000 + i for i in models}


def test_bad_input_gives_clear_errors(tmp_path):
    missing = tmp_path / "nope.mcap"
    result = run("play", missing, "--out", tmp_path / "x.mp4")
    assert_clean_error(result, missing)

    result = run("live", "--rig", BUILTIN_RIG, "--port", "/dev/puppet-no-such-port", "--seconds", 1)
    assert_clean_error(result, "/dev/puppet-no-such-port")

    result = run("record", "--rig", tmp_path / "none.toml", "--port", "/dev/null", "--out", tmp_path / "t.mcap")
    assert_clean_error(result, "none.toml")

    other = tmp_path / "other.mcap"
    with TakeWriter(other, ids=[1, 2], models={1: "XL330-M288", 2: "XL330-M288"}, rig_map_text="",
                    calibration_text="", rig_name="other") as writer:
        writer.write(Reading(0, np.array([1, 2]), np.array([2048, 2048], np.int32), np.ones(2, bool)))
    result = run("play", other, "--rig", BUILTIN_RIG, "--out", tmp_path / "x.mp4")
    assert_clean_error(result, "another rig")

    empty = tmp_path / "empty.mcap"
    TakeWriter(empty, ids=[int(i) for i in _models()], models=_models(), rig_map_text="",
               calibration_text="", rig_name="critter").close()
    result = run("export", empty, "--pc2", tmp_path / "e.pc2")
    assert_clean_error(result, "no readings", empty)

    result = run("scan", "--port", "/dev/puppet-no-such-port")
    assert_clean_error(result, "/dev/puppet-no-such-port")


def _models():
    from puppet.rig import builtin

    return builtin().servo_map.models


def _synthetic_take(path):
    from puppet.rig import builtin

    rig = builtin()
    k = len(rig.servo_map)
    rng = np.random.default_rng(3)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
        for i in range(40):
            ticks = (rig.servo_map.zero + 400 * np.sin(0.2 * i + np.arange(k))).astype(np.int32)
            ticks += rng.integers(-3, 3, k).astype(np.int32)
            writer.write(Reading(i * 25_000_000, rig.servo_map.ids, ticks, np.ones(k, bool)))
    return path


def _children(pid):
    """Pids of the direct children of ``pid`` (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(x) for x in f.read().split()]
    except OSError:
        return []


def _cmdline(pid):
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def test_reader_process_dying_mid_run_is_a_clean_error(tmp_path, wait_until):
    take, video = tmp_path / "live.mcap", tmp_path / "live.mp4"
    with hw_sim.serve(_models(), motion="wave") as bus:
        proc = subprocess.Popen(["puppet", "live", "--rig", str(BUILTIN_RIG), "--port", bus.link,
                                 "--record", str(take), "--out", str(video)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            def reader():  # the bus reader: a spawned child that is not the resource tracker
                return next((c for c in _children(proc.pid) if "spawn_main" in _cmdline(c)
                             and "resource_tracker" not in _cmdline(c)), None)

            def recording():
                try:
                    return len(TakeReader(take)) > 0
                except (OSError, TakeError):
                    return False

            pid = wait_until(reader, timeout=120, what="the reader process")
            wait_until(recording, timeout=120, what="readings in the take")
            os.kill(pid, signal.SIGKILL)
            _, stderr = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    result = subprocess.CompletedProcess(proc.args, proc.returncode, "", stderr)
    assert_clean_error(result, "reader process stopped")
    assert len(TakeReader(take)) > 0                     # the take was closed, readable
    assert imageio_ffmpeg.count_frames_and_secs(str(video))[0] >= 1   # the video was finished


def test_calibrate_names_the_servo_the_bus_cannot_read(tmp_path):
    models = _models()
    gone = sorted(models)[3]
    cal = tmp_path / "cal.toml"
    with hw_sim.serve({i: m for i, m in models.items() if i != gone}) as bus:
        port = bus.port
        result = run("calibrate", "--rig", BUILTIN_RIG, "--port", port, "--out", cal)
    line = assert_clean_error(result, f"servo {gone} ", port)
    assert "did not answer" in line
    assert not cal.exists()


def test_no_egl_is_a_clean_error_naming_the_packages(tmp_path):
    # glvnd finds no EGL vendor library: as on a machine without Mesa's EGL.
    env = dict(os.environ, __EGL_VENDOR_LIBRARY_FILENAMES=str(tmp_path / "none.json"))
    result = subprocess.run(["puppet", "demo", "--seconds", "1", "--out", str(tmp_path / "d.mp4")],
                            capture_output=True, text=True, timeout=300, env=env)
    assert_clean_error(result, "EGL", "libegl1", "libgl1-mesa-dri")
    assert not (tmp_path / "d.mp4").exists()


def test_a_frames_folder_that_cannot_be_written_is_a_clean_error(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    cases = [blocker / "frames"]
    if os.geteuid() != 0:  # root writes into read-only folders: that case only for a user
        read_only = tmp_path / "read-only"
        read_only.mkdir()
        read_only.chmod(0o555)
        cases.append(read_only / "frames")
    with hw_sim.serve(_models(), motion="wave") as bus:
        for frames in cases:
            result = run("live", "--rig", BUILTIN_RIG, "--port", bus.link, "--seconds", 1, "--frames", frames)
            assert_clean_error(result, frames)
