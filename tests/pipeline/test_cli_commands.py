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
from puppet.take import TakeReader, TakeWriter


def run(*args, timeout=120):
    return subprocess.run(["puppet", *map(str, args)], capture_output=True, text=True, timeout=timeout)


def test_demo_writes_a_video_and_a_summary(tmp_path):
    out = tmp_path / "demo.mp4"
    result = run("demo", "--seconds", 2, "--out", out, "--json", "--size", 320, 240)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["frames"] > 5
    assert summary["fps"] > 0
    assert summary["latency_median_ms"] > 0
    assert summary["solver_us_per_iter"] > 0
    frames, _ = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert frames >= 30  # 2 s at 30 fps, repeated frames fill in when rendering is slower
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = next(reader)
    assert tuple(meta["size"]) == (320, 240)


def test_record_killed_then_played_and_exported(tmp_path):
    take = tmp_path / "take.mcap"
    critter_ids = None
    with hw_sim.serve(_models(), motion="wave") as bus:
        proc = subprocess.Popen(["puppet", "record", "--rig", str(BUILTIN_RIG), "--port", bus.port,
                                 "--out", str(take), "--rate", "200"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and (not take.exists() or take.stat().st_size < 20_000):
            time.sleep(0.1)
        time.sleep(0.5)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    reader = TakeReader(take)
    assert len(reader) > 100
    assert reader.metadata.rig_name == "critter"
    readings = list(reader.readings())
    assert all(r.ok.all() for r in readings[-20:])
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
    assert readings > 100
    assert len(TakeReader(take)) == readings
    assert imageio_ffmpeg.count_frames_and_secs(str(video))[0] >= 30


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
    assert result.returncode != 0
    assert str(missing) in result.stderr

    result = run("live", "--rig", BUILTIN_RIG, "--port", "/dev/puppet-no-such-port", "--seconds", 1)
    assert result.returncode != 0
    assert "/dev/puppet-no-such-port" in result.stderr

    result = run("record", "--rig", tmp_path / "none.toml", "--port", "/dev/null", "--out", tmp_path / "t.mcap")
    assert result.returncode != 0
    assert "none.toml" in result.stderr

    other = tmp_path / "other.mcap"
    with TakeWriter(other, ids=[1, 2], models={1: "XL330-M288", 2: "XL330-M288"}, rig_map_text="",
                    calibration_text="", rig_name="other") as writer:
        writer.write(Reading(0, np.array([1, 2]), np.array([2048, 2048], np.int32), np.ones(2, bool)))
    result = run("play", other, "--rig", BUILTIN_RIG, "--out", tmp_path / "x.mp4")
    assert result.returncode != 0
    assert "another rig" in result.stderr

    empty = tmp_path / "empty.mcap"
    TakeWriter(empty, ids=[int(i) for i in _models()], models=_models(), rig_map_text="",
               calibration_text="", rig_name="critter").close()
    result = run("export", empty, "--pc2", tmp_path / "e.pc2")
    assert result.returncode != 0
    assert "no readings" in result.stderr and str(empty) in result.stderr

    result = run("scan", "--port", "/dev/puppet-no-such-port")
    assert result.returncode != 0
    assert "/dev/puppet-no-such-port" in result.stderr


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
