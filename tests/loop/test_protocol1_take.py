"""A take recorded from a Protocol 1.0 rig (AX-12A and MX-28 servos on hw_sim, read through the
real SDK), then played and exported: each model's ticks per turn all the way."""

from __future__ import annotations

import subprocess

import numpy as np

import hw_sim
from puppet.rig import load_rig
from puppet.take import Playback, TakeReader


def run(*args, timeout=300):
    return subprocess.run(["puppet", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def test_a_p1_take_is_recorded_played_and_exported(tmp_path, protocol1_rig):
    rig = load_rig(protocol1_rig)
    models = dict(rig.servo_map.models)
    take = tmp_path / "p1.mcap"
    with hw_sim.serve(models, motion="wave") as bus:
        result = run("record", "--rig", protocol1_rig, "--port", bus.port, "--out", take,
                     "--seconds", 2)
    assert result.returncode == 0, result.stderr
    reader = TakeReader(take)
    assert reader.metadata.models == models
    readings = list(reader.readings())
    assert len(readings) > 10
    ticks = np.stack([r.ticks for r in readings])
    ok = np.stack([r.ok for r in readings])
    assert ok.any(axis=0).all()                        # every servo was read
    assert ticks.std(axis=0).max() > 10                # the wave moved them
    ax = [k for k, i in enumerate(rig.servo_map.ids) if models[int(i)] == "AX-12A"]
    assert ticks[:, ax].min() >= 0 and ticks[:, ax].max() <= 1023   # AX ticks, 1024 positions
    frames = Playback.of_take(reader, rig.servo_map.ids, fps=20)

    bvh = tmp_path / "p1.bvh"
    result = run("export", take, "--fps", 20, "--bvh", bvh)
    assert result.returncode == 0, result.stderr
    motion = bvh.read_text().split("MOTION")[1].splitlines()
    assert motion[1].split() == ["Frames:", str(len(frames))]
    video = tmp_path / "p1.mp4"
    result = run("play", take, "--out", video, "--speed", 2.0)
    assert result.returncode == 0, result.stderr
    assert video.stat().st_size > 0
