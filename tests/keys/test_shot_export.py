"""A shot exports like a take: the glTF holds one frame per shot frame, the sensed joints sit
exactly on each key's pose at its frame, and the free bones move between keys (the in-betweens
are solved, not blended)."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib

from puppet.keys import write_shot
from puppet.keys.example import critter_keys
from puppet.rig import builtin
from puppet.rig.calibration import Calibration

PUPPET = Path(sys.executable).with_name("puppet")
_spec = importlib.util.spec_from_file_location(
    "keys_export_readers", Path(__file__).parents[1] / "export" / "readers.py")
readers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readers)
accessor, trs, worlds = readers.accessor, readers.trs, readers.worlds


def test_gltf_of_a_shot_has_the_key_poses_at_their_frames(tmp_path):
    rig = builtin()
    keys = critter_keys(rig, step=12, fps=24)
    shot = tmp_path / "shot.mcap"
    header = {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
              "rig_map_text": "", "rig_name": rig.name,
              "calibration_text": Calibration.capture(rig.servo_map.ids,
                                                      rig.servo_map.zero).to_record()}
    write_shot(shot, header, keys)
    out = tmp_path / "shot.glb"
    result = subprocess.run([str(PUPPET), "export", str(shot), "--fps", "24", "--gltf", str(out)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    gltf = pygltflib.GLTF2().load_binary(str(out))
    anim = gltf.animations[0]
    channels = {(c.target.node, c.target.path): accessor(gltf, anim.samplers[c.sampler].output)
                for c in anim.channels}
    b = rig.skeleton.bone_count
    assert len(channels[0, "rotation"]) == 37  # the last key's frame
    skin = gltf.skins[0]
    ibm = accessor(gltf, skin.inverseBindMatrices).reshape(b, 4, 4).transpose(0, 2, 1)
    full = rig.full_bones
    for key in keys.keys:
        f = key.frame - 1
        world = worlds(gltf, {j: trs(channels[j, "translation"][f], channels[j, "rotation"][f])
                              for j in range(b)})
        fk = rig.pose(rig.servo_map.angles(key.ticks))
        np.testing.assert_allclose((world @ ibm)[full, :3, :], fk[full], atol=2e-5)
    free = [rig.skeleton.index(n) for n in rig.bone_kinds()["free"]]
    rotations = np.stack([channels[j, "rotation"] for j in free], 1)  # (frames, free, 4)
    for a, z in zip(keys.keys[:-1], keys.keys[1:]):
        for f in range(a.frame, z.frame - 1):  # every in-between, 0-based
            assert np.abs(rotations[f] - rotations[f - 1]).max() > 0, f


def _channels(path):
    gltf = pygltflib.GLTF2().load_binary(str(path))
    anim = gltf.animations[0]
    return {(c.target.node, c.target.path): (accessor(gltf, anim.samplers[c.sampler].input),
                                             accessor(gltf, anim.samplers[c.sampler].output))
            for c in anim.channels}


def test_reduced_gltf_of_a_shot_keys_every_channel_at_the_key_poses(tmp_path):
    """``export --keys TOL`` of a shot: every channel has a key at each key pose's frame, reads
    back within TOL of the per-frame export at every frame, and holds fewer keys than frames."""
    import json

    from puppet.export.key_reduction import curve_error

    _, keys, shot = _shot(tmp_path)
    full, reduced, tol = tmp_path / "full.glb", tmp_path / "reduced.glb", 0.5
    for out, extra in ((full, []), (reduced, ["--keys", str(tol), "--json"])):
        result = subprocess.run([str(PUPPET), "export", str(shot), "--fps", "24", "--gltf", str(out),
                                 *extra], capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.splitlines()[-1])["keys"]
    assert report["key_poses"] == len(keys.keys)
    every, kept = _channels(full), _channels(reduced)
    frames = len(next(iter(every.values()))[0])
    assert frames == keys.keys[-1].frame
    times = next(iter(every.values()))[0].astype(np.float64)
    key_times = np.array([k.frame for k in keys.keys]) / 24.0  # frame k at k/fps
    total = 0
    for (node, path), (key_t, _) in kept.items():
        values = every[node, path][1].astype(np.float64)
        index = np.rint(key_t * 24.0).astype(int) - 1
        np.testing.assert_allclose(times[index], key_t, atol=1e-6)
        assert set(np.rint(key_times * 24).astype(int) - 1) <= set(index.tolist()), (node, path)
        error = curve_error(times, values, index, path)
        limit = tol if path == "rotation" else report["translation_units"]
        assert error.max() <= limit + 1e-4, (node, path, error.max())
        total += len(index)
    assert total == report["kept"] < report["every_frame"] == len(kept) * frames
    print(f"shot of {len(keys.keys)} keys, {frames} frames, {len(kept)} channels: "
          f"{report['kept']} keys of {report['every_frame']} ({report['kept_pct']:.1f} %) within "
          f"{tol}° / {report['translation_units']:.4g} units")


def _shot(tmp_path):
    rig = builtin()
    keys = critter_keys(rig, step=12, fps=24)
    shot = tmp_path / "shot.mcap"
    header = {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
              "rig_map_text": "", "rig_name": rig.name,
              "calibration_text": Calibration.capture(rig.servo_map.ids,
                                                      rig.servo_map.zero).to_record()}
    write_shot(shot, header, keys)
    return rig, keys, shot


def _pc2_samples(path) -> int:
    import struct

    head = Path(path).read_bytes()[:32]
    assert head[:12] == b"POINTCACHE2\0"
    return struct.unpack("<iiffi", head[12:32])[4]


def test_every_export_format_and_batch_take_a_shot(tmp_path):
    """A shot is a take: ``export`` writes glTF, USD, PC2 and BVH of it in one run, and
    ``batch`` exports it, each with one frame per shot frame (the last key's frame)."""
    import json

    from pxr import Usd

    rig, keys, shot = _shot(tmp_path)
    last = keys.keys[-1].frame
    out = {fmt: tmp_path / f"shot.{ext}" for fmt, ext in
           (("gltf", "glb"), ("usd", "usdc"), ("pc2", "pc2"), ("bvh", "bvh"))}
    args = [a for fmt, path in out.items() for a in (f"--{fmt}", str(path))]
    result = subprocess.run([str(PUPPET), "export", str(shot), "--fps", "24", *args, "--json"],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.splitlines()[-1])["frames"] == last
    assert len(_channels(out["gltf"])[0, "rotation"][0]) == last
    stage = Usd.Stage.Open(str(out["usd"]))
    assert stage.GetEndTimeCode() - stage.GetStartTimeCode() + 1 == last
    assert _pc2_samples(out["pc2"]) == last
    assert f"Frames: {last}" in out["bvh"].read_text()

    batch = subprocess.run([str(PUPPET), "batch", str(shot), "--out", str(tmp_path / "batch"),
                            "--formats", "gltf,pc2", "--fps", "24", "--workers", "1"],
                           capture_output=True, text=True, timeout=600)
    assert batch.returncode == 0, batch.stderr + batch.stdout
    assert _pc2_samples(tmp_path / "batch" / "shot.pc2") == last
    assert len(_channels(tmp_path / "batch" / "shot.glb")[0, "rotation"][0]) == last
