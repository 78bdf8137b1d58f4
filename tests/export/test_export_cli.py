"""``puppet export`` as a user runs it: resampled frame counts, byte-identical reruns, and clear
errors (an ``Error:`` line, exit 1, no traceback) with nothing half-written left behind."""

import os
import resource
import subprocess
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from puppet.bus import Reading
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader, TakeWriter


def run(*args, limit_bytes=None):
    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return subprocess.run(["puppet", "export", *map(str, args)], capture_output=True, text=True,
                          timeout=300, preexec_fn=limit if limit_bytes else None)


def assert_clean_error(result, *words):
    assert result.returncode == 1, result.stderr
    assert "Error:" in result.stderr
    assert "Traceback" not in result.stderr
    for word in words:
        assert word in result.stderr, result.stderr


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".partial" in p.name)


def test_fps_24_from_a_30_fps_take_is_resampled_and_byte_identical(tmp_path, take30):
    reader = TakeReader(take30)
    span_s = (reader.t_last_ns - reader.t_first_ns) / 1e9
    expected = int(np.floor(span_s * 24 + 1e-9)) + 1
    runs = []
    for i in range(2):
        files = {f: tmp_path / f"run{i}.{ext}" for f, ext in
                 (("gltf", "glb"), ("usd", "usdc"), ("pc2", "pc2"), ("bvh", "bvh"))}
        result = run(take30, "--fps", 24, *[a for f, p in files.items() for a in (f"--{f}", p)])
        assert result.returncode == 0, result.stderr
        assert f"frames: {expected} at 24 fps (frame 1 = the first reading" in result.stdout
        runs.append({f: p.read_bytes() for f, p in files.items()})
    assert runs[0] == runs[1]
    num_samples = np.frombuffer(runs[0]["pc2"][28:32], np.int32)[0]
    assert num_samples == expected
    assert f"Frames: {expected}" in runs[0]["bvh"].decode()
    gltf = pygltflib.GLTF2().load_binary(str(tmp_path / "run0.glb"))
    assert gltf.accessors[gltf.animations[0].samplers[0].input].count == expected
    assert leftovers(tmp_path) == []


def test_bad_rates_are_refused(tmp_path, take30):
    for fps in ("0", "-24"):  # the others (nan, inf, words) in tests/take/test_take_playback.py
        result = run(take30, "--pc2", tmp_path / "m.pc2", "--fps", fps)
        assert_clean_error(result, "frames per second must be")
    assert not (tmp_path / "m.pc2").exists()


def test_a_take_from_another_rig_names_both_rigs(tmp_path):
    other = tmp_path / "other.mcap"
    with TakeWriter(other, ids=[1, 2], models={1: "XL330-M288", 2: "XL330-M288"},
                    rig_map_text="", calibration_text="", rig_name="other") as writer:
        writer.write(Reading(0, np.array([1, 2]), np.array([2048, 2048], np.int32),
                             np.ones(2, bool)))
    result = run(other, "--pc2", tmp_path / "m.pc2")  # no --rig: the take's own rig, not stored
    assert_clean_error(result, "'other'", "--rig")
    result = run(other, "--rig", BUILTIN_RIG, "--gltf", tmp_path / "a.glb")
    assert_clean_error(result, "another rig", "'other'", "'critter'")
    assert list(tmp_path.iterdir()) == [other]


def test_an_empty_take_is_refused(tmp_path, critter):
    empty = tmp_path / "empty.mcap"
    TakeWriter(empty, ids=[int(i) for i in critter.servo_map.ids],
               models=dict(critter.servo_map.models), rig_map_text="", calibration_text="",
               rig_name="critter").close()
    result = run(empty, "--usd", tmp_path / "a.usdc")
    assert_clean_error(result, str(empty), "no readings")
    assert list(tmp_path.iterdir()) == [empty]


def test_the_take_itself_is_never_an_output(tmp_path, take30):
    before = Path(take30).read_bytes()
    result = run(take30, "--bvh", take30)
    assert_clean_error(result, "also an input")
    assert Path(take30).read_bytes() == before


def test_outputs_named_for_another_format_are_refused(tmp_path, take30):
    result = run(take30, "--usd", tmp_path / "anim.txt")
    assert_clean_error(result, "anim.txt", "--usd files are named *.usdc or *.usda or *.usd")
    result = run(take30, "--gltf", tmp_path / "anim.gltf")  # the export is binary glTF
    assert_clean_error(result, "anim.gltf", "--gltf files are named *.glb")
    result = run(take30, "--pc2", tmp_path / "same.out", "--bvh", tmp_path / "same.out")
    assert_clean_error(result, "given for both --pc2 and --bvh")
    assert list(tmp_path.iterdir()) == []


def test_an_unwritable_folder_is_refused(tmp_path, take30):
    if os.geteuid() == 0:  # root writes through file modes: a folder no one can create files in
        folder = Path("/proc/self")
    else:
        folder = tmp_path / "locked"
        folder.mkdir()
        folder.chmod(0o555)
    result = run(take30, "--gltf", folder / "anim.glb")
    assert_clean_error(result, str(folder), "not writable")


@pytest.mark.parametrize("fmt", ["pc2", "usd", "gltf"])
def test_a_full_disk_keeps_the_good_file_and_leaves_no_half_file(tmp_path, take30, fmt):
    """The file size limit stops writes part-way as a full disk does (EFBIG instead of ENOSPC)."""
    target = tmp_path / {"pc2": "mesh.pc2", "usd": "anim.usdc", "gltf": "anim.glb"}[fmt]
    good = {"pc2": b"POINTCACHE2\0", "usd": b"PXR-USDC", "gltf": b"glTF"}[fmt] + b" from before"
    target.write_bytes(good)  # a file of the format's kind (another kind is refused up front)
    result = run(take30, f"--{fmt}", target, limit_bytes=400_000)
    assert_clean_error(result, str(target), "cannot write")
    assert target.read_bytes() == good
    assert leftovers(tmp_path) == []
