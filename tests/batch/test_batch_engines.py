"""``puppet batch`` on both engines: outputs byte-identical to the serial commands, one row per
take, nothing left in staging."""

import json
import subprocess
import tempfile

import pytest

from puppet.batch import SUFFIXES

ALL = ("mp4", "gltf", "usd", "pc2", "bvh")


def run_batch(*args, timeout=600):
    # Run from a neutral folder, as a user does: Ray puts the driver's working folder on its
    # workers' import path, and the repository root holds the source tree (no built _native).
    return subprocess.run(["puppet", "batch", *map(str, args), "--json"], capture_output=True,
                          text=True, timeout=timeout, cwd=tempfile.gettempdir())


def assert_outputs_equal(out, serial_outputs, formats):
    for take, files in serial_outputs.items():
        for fmt in formats:
            assert (out / f"{take}{SUFFIXES[fmt]}").read_bytes() == files[fmt], (take, fmt)
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []


def test_local_engine_matches_the_serial_commands(tmp_path, session, serial_outputs):
    out = tmp_path / "out"
    result = run_batch(*session, "--out", out, "--formats", ",".join(ALL), "--workers", 2)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert [row["take"] for row in report["takes"]] == [str(t) for t in session]
    assert all(row["state"] == "done" and row["frames"] == 10 for row in report["takes"])
    assert report["workers"] == 2
    assert report["precompute_bytes"] > 1_000_000  # the critter's FastModel and factor, sent once
    assert_outputs_equal(out, serial_outputs, ALL)


@pytest.mark.xdist_group("batch-ray")  # one Ray instance at a time (tests/conftest.py)
def test_ray_engine_matches_the_serial_commands(tmp_path, session, serial_outputs, request):
    pytest.importorskip("ray", reason="ray is not installed (pip install 'puppet[ray]')")
    out = tmp_path / "out"
    formats = ("mp4", "gltf", "pc2")
    # on the session's Ray cluster of 2 CPUs (a private instance: test_batch_ray_address.py)
    result = run_batch(*session, "--out", out, "--formats", ",".join(formats), "--engine", "ray",
                       "--workers", 2, *request.getfixturevalue("on_ray_cluster"))
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["engine"] == "ray"
    assert all(row["state"] == "done" for row in report["takes"])
    assert_outputs_equal(out, serial_outputs, formats)
