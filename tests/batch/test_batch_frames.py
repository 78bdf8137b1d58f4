"""One take-to-frames rule and one solve per take: ``puppet batch`` of a take with a gap writes the
same frames into every format (count and pose), and a take whose readings are hours apart is cut
and warned about in ``play``, ``export`` and ``batch`` alike."""

import importlib.util
import json
import re
import subprocess
import tempfile
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pygltflib
import pytest

from puppet.export import SourceOrder
from puppet.reading import Reading
from puppet.take import MAX_GAP_S, Playback, TakeReader, TakeWriter

_spec = importlib.util.spec_from_file_location(
    "batch_frames_readers", Path(__file__).parents[1] / "export" / "readers.py")
readers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readers)  # the tests' readers of the exported files

FPS = 30
GAP_S = 3.0


def write_gap_take(path, rig, gap_ns, per_side=13):
    """Readings at 30 Hz, every servo moving, then ``gap_ns`` of silence, then as many again."""
    k = len(rig.servo_map)
    times = [round(i * 1e9 / 30) for i in range(per_side)]
    times += [times[-1] + gap_ns + round(i * 1e9 / 30) for i in range(per_side)]
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name, overwrite=True) as w:
        for i, t in enumerate(times):
            ticks = (rig.servo_map.zero + 400 * np.sin(0.3 * i + np.arange(k))).astype(np.int32)
            w.write(Reading(2_000_000_000 + t, rig.servo_map.ids, ticks, np.ones(k, bool)))
    return path


def puppet(*args, timeout=600):
    return subprocess.run(["puppet", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=tempfile.gettempdir())


def video_frames(path) -> int:
    """Frames an mp4 decodes to (imageio's ffmpeg reader; the first item is its metadata)."""
    reader = imageio_ffmpeg.read_frames(str(path))
    next(reader)
    return sum(1 for _ in reader)


@pytest.fixture(scope="module")
def gap_batch(tmp_path_factory, critter):
    """A take with a 3 s gap, its batch in every format, and the rule's frames solved here."""
    from puppet.loop import Pipeline

    folder = tmp_path_factory.mktemp("gap")
    take = write_gap_take(folder / "gap.mcap", critter, int(GAP_S * 1e9))
    out = folder / "out"
    result = puppet("batch", take, "--out", out, "--formats", "mp4,gltf,usd,pc2,bvh",
                    "--fps", FPS, "--size", 160, 120, "--json")
    assert result.returncode == 0, result.stderr
    frames = Playback.of_take(TakeReader(take), critter.servo_map.ids, fps=FPS)
    Ts = []
    with Pipeline(critter, render=False) as pipeline:
        M = pipeline.model.lbs_matrix()  # (n, 4m): V' = M T
        for reading in frames:
            pipeline.solve(reading)
            Ts.append(pipeline.T.copy())
    return take, out, json.loads(result.stdout), frames, np.array(Ts), M, result.stderr


def test_every_format_of_a_gap_take_has_the_same_frames(gap_batch, critter):
    take, out, report, frames, Ts, M, stderr = gap_batch
    # 12 readings' time, the 3 s gap cut to MAX_GAP_S, 12 more: 1.8 s at 30 fps.
    N = len(frames)
    assert N == round((24 / 30 + MAX_GAP_S) * FPS) + 1 == 55
    assert frames.cuts and frames.cuts[0].gap_ns > MAX_GAP_S * 1e9
    assert report["takes"][0]["frames"] == N
    assert "gap(s) between readings longer than 1 s" in stderr

    assert video_frames(out / "gap.mp4") == N

    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out / "gap.usdc"))
    points = UsdGeom.Mesh(stage.GetPrimAtPath(stage.GetDefaultPrim().GetPath().AppendChild("Mesh")))
    points = points.GetPointsAttr()
    assert points.GetTimeSamples() == [float(k) for k in range(1, N + 1)]
    header, pc2 = readers.read_pc2(out / "gap.pc2")
    samples = header["num_samples"]
    assert samples == N
    gltf = pygltflib.GLTF2().load_binary(str(out / "gap.glb"))
    b = critter.skeleton.bone_count
    pivots_gltf, key_counts = readers.key_pivots(gltf, b)
    assert set(key_counts) == {N}
    bvh = readers.read_bvh((out / "gap.bvh").read_text())
    names, pivots_bvh, bvh_frames = bvh.names, readers.pivots(bvh), len(bvh.motion)
    assert bvh_frames == N

    # Frame k is one pose in every file: the mesh formats bit for bit, the joints at the solve's
    # pivots (to the file's float precision), the solve being the rule's frames solved here.
    order = SourceOrder(critter)
    heads = np.hstack([critter.skeleton.heads, np.ones((b, 1))])
    bvh_order = [critter.skeleton.names.index(n) for n in names]
    for f in range(N):
        usd = np.asarray(points.Get(Usd.TimeCode(f + 1)), np.float32)
        np.testing.assert_array_equal(usd, pc2[f])
        mesh = order.take(M @ Ts[f].astype(np.float64))
        np.testing.assert_allclose(pc2[f], mesh, rtol=0, atol=2e-6)
        solved = np.einsum("bi,bij->bj", heads, Ts[f].reshape(-1, 4, 3)[:b].astype(np.float64))
        np.testing.assert_allclose(pivots_gltf[f], solved, atol=2e-5)
        np.testing.assert_allclose(pivots_bvh[f], solved[bvh_order], atol=2e-5)


def test_readings_hours_apart_are_cut_and_warned_in_every_command(tmp_path, critter):
    hours = 2 * 3600 * 10**9
    take = write_gap_take(tmp_path / "hours.mcap", critter, hours, per_side=5)
    expected = len(Playback.of_take(TakeReader(take), critter.servo_map.ids, fps=10))
    assert expected == int((8 / 30 + MAX_GAP_S) * 10) + 1  # not two hours of frames

    def warned(stderr):
        assert "1 gap(s) between readings longer than 1 s (the longest 7200.000 s (2.0 h)" in stderr
        assert "playback cuts them to 1 s in every output" in stderr

    play = puppet("play", take, "--out", tmp_path / "hours.mp4", "--fps", 10)
    assert play.returncode == 0, play.stderr
    warned(play.stderr)
    assert re.search(rf"^frames {expected} in ", play.stdout, re.M)
    assert video_frames(tmp_path / "hours.mp4") == expected

    export = puppet("export", take, "--pc2", tmp_path / "hours.pc2", "--fps", 10, "--json")
    assert export.returncode == 0, export.stderr
    warned(export.stderr)
    report = json.loads(export.stdout)
    assert report["frames"] == expected == readers.read_pc2(tmp_path / "hours.pc2")[0]["num_samples"]
    assert [round(c["gap_s"]) for c in report["gaps_cut"]] == [7200]

    batch = puppet("batch", take, "--out", tmp_path / "out", "--formats", "mp4,pc2", "--fps", 10,
                   "--size", 160, 120, "--json")
    assert batch.returncode == 0, batch.stderr
    warned(batch.stderr)
    assert json.loads(batch.stdout)["takes"][0]["frames"] == expected
    assert readers.read_pc2(tmp_path / "out" / "hours.pc2")[0]["num_samples"] == expected
    assert video_frames(tmp_path / "out" / "hours.mp4") == expected
