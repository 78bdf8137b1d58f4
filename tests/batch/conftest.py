"""Shared data of the batch tests: short takes of the built-in critter, written with TakeWriter,
and each take exported and played alone by the serial commands (the reference bytes)."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.take import TakeWriter

READINGS = 10  # a third of a second at 30 readings per second: 10 frames per output
SERIAL_FORMATS = {"gltf": ".glb", "usd": ".usdc", "pc2": ".pc2", "bvh": ".bvh"}


def write_take(path, rig, readings=READINGS, seed=0, rig_name=None):
    """A take of ``rig`` at 30 readings per second, every servo moving (``seed`` varies it)."""
    k = len(rig.servo_map)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig_name or rig.name,
                    overwrite=True) as writer:
        for i in range(readings):
            ticks = (rig.servo_map.zero + 300 * np.sin(0.2 * i + seed + np.arange(k))).astype(np.int32)
            writer.write(Reading(1_000_000_000 + round(i * 1e9 / 30), rig.servo_map.ids, ticks,
                                 np.ones(k, bool)))
    return Path(path)


def serial(take: Path, folder: Path, formats) -> dict[str, bytes]:
    """{format: bytes} of ``puppet export`` / ``puppet play`` run on the take alone."""
    folder.mkdir(exist_ok=True)
    exports = [f for f in formats if f in SERIAL_FORMATS]
    files = {f: folder / f"{take.stem}{SERIAL_FORMATS[f]}" for f in exports}
    if exports:
        args = [a for f in exports for a in (f"--{f}", files[f])]
        subprocess.run(["puppet", "export", take, *args], check=True, capture_output=True,
                       timeout=300)
    if "mp4" in formats:
        files["mp4"] = folder / f"{take.stem}.mp4"
        subprocess.run(["puppet", "play", take, "--out", files["mp4"]], check=True,
                       capture_output=True, timeout=300)
    return {f: p.read_bytes() for f, p in files.items()}


@pytest.fixture(scope="session")
def critter():
    from puppet.rig import builtin

    return builtin()


@pytest.fixture(scope="session")
def session(tmp_path_factory, critter):
    """Four short takes of the critter, different motions: [Path]."""
    folder = tmp_path_factory.mktemp("session")
    return [write_take(folder / f"take{i:02d}.mcap", critter, seed=i) for i in range(4)]


@pytest.fixture(scope="session")
def serial_outputs(tmp_path_factory, session):
    """{take name: {format: bytes}} of every format made by the serial commands."""
    folder = tmp_path_factory.mktemp("serial")
    return {take.stem: serial(take, folder, ("mp4", "gltf", "usd", "pc2", "bvh")) for take in session}


@pytest.fixture
def tools():
    from types import SimpleNamespace

    return SimpleNamespace(write_take=write_take, serial=serial)
