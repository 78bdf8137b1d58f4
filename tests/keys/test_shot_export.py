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
