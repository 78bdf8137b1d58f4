"""Shared data of the export tests: a 30 fps take of the built-in critter with irregular reading
times, its independent reference solve at 24 fps, and one export of it in every format."""

from dataclasses import dataclass

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.take import TakeWriter

FPS = 24.0
TAKE_FPS = 30
READINGS = 46  # 1.5 s at 30 fps: 37 frames at 24 fps


def write_take(path, rig, readings=READINGS, jitter_ns=3_000_000, seed=5, rig_name=None,
               sound=None):
    """A take of ``rig`` at about 30 readings per second, times jittered, every servo moving
    (sound: the take's SoundRef, or None)."""
    k = len(rig.servo_map)
    rng = np.random.default_rng(seed)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig_name or rig.name,
                    sound=sound, overwrite=True) as writer:
        for i in range(readings):
            ticks = (rig.servo_map.zero + 380 * np.sin(0.15 * i + np.arange(k))).astype(np.int32)
            t = 5_000_000_000 + round(i * 1e9 / TAKE_FPS)
            if 0 < i < readings - 1:
                t += int(rng.integers(-jitter_ns, jitter_ns))
            writer.write(Reading(t, rig.servo_map.ids, ticks, np.ones(k, bool)))
    return path


@dataclass
class Reference:
    """The solve of every resampled frame, made here with the pipeline itself."""

    times_ns: np.ndarray   # (N,)
    deformed: np.ndarray   # (N, n, 3) float64, Pipeline.deformed()
    T: np.ndarray          # (N, 4m, 3) float32
    angles: np.ndarray     # (N, k) radians


def reference_solve(rig, take_path, fps=FPS) -> Reference:
    from puppet.loop import Pipeline
    from puppet.take import Playback, TakeReader

    ids = rig.servo_map.ids
    frames = Playback.of_take(TakeReader(take_path), ids, fps=fps)
    deformed, Ts, angles = [], [], []
    with Pipeline(rig, render=False) as pipeline:
        for reading in frames:
            pipeline.solve(reading)
            deformed.append(pipeline.deformed())
            Ts.append(pipeline.T.copy())
            angles.append(pipeline.angles.copy())
    return Reference(frames.t_first_ns + frames.frame_times_ns(), np.array(deformed), np.array(Ts), np.array(angles))


@pytest.fixture(scope="session")
def fps():
    """Frame rate of the shared export (the take is 30 fps)."""
    return FPS


@pytest.fixture(scope="session")
def critter():
    from puppet.rig import builtin

    return builtin()


@pytest.fixture(scope="session")
def take30(tmp_path_factory, critter):
    return write_take(tmp_path_factory.mktemp("take") / "take30.mcap", critter)


@pytest.fixture(scope="session")
def reference(critter, take30):
    return reference_solve(critter, take30)


@pytest.fixture(scope="session")
def exported(tmp_path_factory, critter, take30):
    """(paths {format: Path}, ExportReport) of one export in every format at 24 fps."""
    from puppet.export import Outputs, export_take
    from puppet.take import TakeReader

    folder = tmp_path_factory.mktemp("out")
    paths = {"gltf": folder / "anim.glb", "usd": folder / "anim.usdc",
             "pc2": folder / "mesh.pc2", "bvh": folder / "skeleton.bvh"}
    report = export_take(critter, TakeReader(take30), Outputs(**paths), fps=FPS)
    return paths, report
