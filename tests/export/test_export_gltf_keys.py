"""`puppet export --keys DEG`: the glTF of the built-in 10 s take (the demo's performance) keeps few
LINEAR keys, read back at every frame within the tolerance by the glTF spec's evaluation (scipy's
Slerp), Blender's (per-component lerp, normalized) and Blender 5.0 itself (bpy); bad tolerances
are refused naming the option."""

import importlib.util
import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation, Slerp

from puppet.bus import Reading
from puppet.demo import DEMO_READ_RATE_HZ, Performance
from puppet.export import ExportError, Outputs, export_take
from puppet.take import TakeReader, TakeWriter

TOL = 0.5  # degrees, the figure
FPS = 30.0
SECONDS = 10.0


def load_module(relative: str):
    """A test helper module by path (pytest runs with --import-mode=importlib: no packages)."""
    path = Path(__file__).parents[1] / relative
    spec = importlib.util.spec_from_file_location("export_keys_" + path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


accessor = load_module("export/readers.py").accessor
blender = load_module("export/blender/run_bpy.py")  # Blender (bpy) in a subprocess


def demo_take(path, rig):
    """The built-in take: 10 s of ``puppet demo``'s performance of the critter, read at the demo's
    bus rate (DEMO_READ_RATE_HZ), ticks rounded as the bus reports them."""
    perf = Performance(rig)
    ids = rig.servo_map.ids
    with TakeWriter(path, ids=[int(i) for i in ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
        for i in range(int(SECONDS * DEMO_READ_RATE_HZ) + 1):
            t = i / DEMO_READ_RATE_HZ
            ticks = np.array([perf.position(s, t) for s in ids]).round().astype(np.int32)
            writer.write(Reading(round(t * 1e9), ids, ticks, np.ones(len(ids), bool)))
    return path


@pytest.fixture(scope="module")
def exports(tmp_path_factory, critter):
    """(every-frame glb, reduced glb, the reduced export's --json report)."""
    folder = tmp_path_factory.mktemp("keys")
    take = demo_take(folder / "demo10.mcap", critter)
    full, reduced = folder / "full.glb", folder / "reduced.glb"
    export_take(critter, TakeReader(take), Outputs(gltf=full), fps=FPS)
    done = subprocess.run(["puppet", "export", str(take), "--rig", str(critter.path), "--gltf",
                           str(reduced), "--fps", str(FPS), "--keys", str(TOL), "--json"],
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    return full, reduced, json.loads(done.stdout.splitlines()[-1])


def channels(path):
    """{(joint name, path): (times (K,), values (K, c), interpolation)} of animation 0."""
    gltf = pygltflib.GLTF2().load_binary(str(path))
    animation = gltf.animations[0]
    out = {}
    for channel in animation.channels:
        sampler = animation.samplers[channel.sampler]
        key = (gltf.nodes[channel.target.node].name, channel.target.path)
        out[key] = (accessor(gltf, sampler.input).astype(np.float64),
                    accessor(gltf, sampler.output).astype(np.float64), sampler.interpolation)
    return gltf, out


def test_the_reduced_gltf_reads_back_within_the_tolerance_at_every_frame(exports, critter):
    full_path, reduced_path, report = exports
    _, full = channels(full_path)
    gltf, reduced = channels(reduced_path)
    units = report["keys"]["translation_units"]
    assert report["keys"]["rotation_deg"] == TOL
    assert math.isclose(units, math.radians(TOL) * np.linalg.norm(critter.V.max(0) - critter.V.min(0)))
    N = report["frames"]
    assert N == round(SECONDS * FPS) + 1
    assert sorted(full) == sorted(reduced) and len(full) == 2 * critter.skeleton.bone_count
    for key, (times, values, interpolation) in reduced.items():
        all_times, samples, _ = full[key]
        assert interpolation == "LINEAR" and len(all_times) == N
        assert times[0] == all_times[0] and times[-1] == all_times[-1]
        assert np.isin(times, all_times).all()  # keys sit on frames
        if key[1] == "rotation":
            spec = Slerp(times, Rotation.from_quat(values))(all_times)
            q = np.stack([np.interp(all_times, times, values[:, c]) for c in range(4)], 1)
            blender = Rotation.from_quat(q / np.linalg.norm(q, axis=1, keepdims=True))
            for read in (spec, blender):
                error = np.degrees((read.inv() * Rotation.from_quat(samples)).magnitude())
                assert error.max() <= TOL + 1e-3, key  # float32 values and times
        else:
            lerp = np.stack([np.interp(all_times, times, values[:, c]) for c in range(3)], 1)
            assert np.linalg.norm(lerp - samples, axis=1).max() <= units + 1e-5, key
    assert gltf.scenes[gltf.scene].extras == {"puppet_fps": FPS, "puppet_frame_start": 1,
                                              "puppet_frame_end": N}


def test_fewer_than_a_quarter_of_the_keys_remain(exports, critter):
    _, reduced_path, report = exports
    _, reduced = channels(reduced_path)
    keys = report["keys"]
    in_file = {(name, path): len(times) for (name, path), (times, _, _) in reduced.items()}
    assert keys["joints"] == {name: {"translation": in_file[(name, "translation")],
                                     "rotation": in_file[(name, "rotation")]}
                              for name in critter.skeleton.names}
    assert keys["kept"] == sum(in_file.values())
    assert keys["every_frame"] == 2 * critter.skeleton.bone_count * report["frames"]
    print(f"\nkeys kept at {TOL}°: {keys['kept']} of {keys['every_frame']} ({keys['kept_pct']:.1f} %)")
    assert keys["kept"] < keys["every_frame"] / 4


BLENDER_POSES = """
import bpy, json, sys
out = {}
for label, path in (("full", sys.argv[1]), ("reduced", sys.argv[2])):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = int(sys.argv[3]), 1.0
    bpy.ops.import_scene.gltf(filepath=path)
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    start, end = scene["puppet_frame_start"], scene["puppet_frame_end"]
    poses = []
    for frame in range(start, end + 1):
        scene.frame_set(frame)
        poses.append({b.name: list(b.rotation_quaternion) + list(b.location) for b in arm.pose.bones})
    out[label] = {"range": list(arm.animation_data.action.frame_range), "poses": poses,
                  "extras": [start, end, scene["puppet_fps"]]}
print("RESULT " + json.dumps(out))
"""


@pytest.mark.skipif(blender.bpy_missing() is not None, reason=str(blender.bpy_missing()))
def test_blender_plays_the_reduced_keys_within_the_tolerance(exports):
    full_path, reduced_path, report = exports
    got = blender.run_bpy_result(BLENDER_POSES, full_path, reduced_path, int(FPS))
    N = report["frames"]
    for label in ("full", "reduced"):
        assert got[label]["range"] == [1.0, float(N)]
        assert got[label]["extras"] == [1, N, FPS]
    units = report["keys"]["translation_units"]
    worst_deg = worst_units = 0.0
    for full, reduced in zip(got["full"]["poses"], got["reduced"]["poses"], strict=True):
        for bone, a in full.items():
            b = np.array(reduced[bone])
            a = np.array(a)
            qa, qb = a[:4] / np.linalg.norm(a[:4]), b[:4] / np.linalg.norm(b[:4])  # Blender normalizes
            chord = min(np.linalg.norm(qa - qb), np.linalg.norm(qa + qb))  # either sign
            angle = np.degrees(4 * np.arcsin(min(1.0, chord / 2)))
            worst_deg = max(worst_deg, angle)
            worst_units = max(worst_units, float(np.linalg.norm(a[4:] - b[4:])))
    print(f"\nBlender: reduced vs every-frame keys, worst {worst_deg:.3f}° and {worst_units:.2e} units")
    assert 0.0 < worst_deg <= TOL + 1e-3  # the keys differ, and stay within the tolerance
    assert worst_units <= units + 1e-5


@pytest.mark.parametrize("option, value", [("--keys", "0"), ("--keys", "-1"), ("--keys", "nan"),
                                           ("--keys", "inf"), ("--keys", "91"),
                                           ("--keys-units", "0"), ("--keys-units", "nan")])
def test_bad_key_tolerances_are_refused_naming_the_option(tmp_path, take30, option, value):
    args = ["puppet", "export", str(take30), "--gltf", str(tmp_path / "a.glb"), option, value]
    if option != "--keys":
        args += ["--keys", "0.5"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert done.returncode == 2
    assert f"Invalid value for '{option}'" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "a.glb").exists()


def test_key_tolerances_are_checked_by_the_api_too(tmp_path, critter, take30):
    for keys, units, option in ((0.0, None, "--keys"), (float("nan"), None, "--keys"),
                                (1.0, -2.0, "--keys-units"), (None, 0.1, "--keys-units")):
        with pytest.raises(ExportError) as error:
            export_take(critter, TakeReader(take30), Outputs(gltf=tmp_path / "a.glb"), keys=keys,
                        keys_units=units)
        assert error.value.path == option
    with pytest.raises(ExportError) as error:  # BVH stays per frame
        export_take(critter, TakeReader(take30), Outputs(bvh=tmp_path / "a.bvh"), keys=0.5)
    assert error.value.path == "--keys" and "--gltf" in error.value.reason
    assert not (tmp_path / "a.glb").exists() and not (tmp_path / "a.bvh").exists()
