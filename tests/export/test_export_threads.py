"""Exports do not depend on the machine's BLAS thread settings: the same take gives byte-identical
glTF, USD, PC2 and BVH files with the thread variables at 1, 2 or unset, from the command line
and from the Python API (in a fresh interpreter and in this one).

The rig is the built-in critter with 300 rotation clusters and 30 extra weights: with the
precompute run on the BLAS's own threads, its 2-thread export differed from the 1-thread one
(vertices up to about 1e-4 of the diagonal apart); the critter's own 100 clusters and 8 extra
weights happen to round to the same bytes. Each run gets a fresh cache folder, so each really
computes the precompute (a shared cache would hand every run the first run's matrices).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from puppet.reading import Reading
from puppet.rig.load import BUILTIN_RIG, load_rig
from puppet.take import TakeWriter

THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
FORMATS = {"usd": "anim.usdc", "pc2": "mesh.pc2", "bvh": "skeleton.bvh", "gltf": "anim.glb"}
COMPARED = ("usd", "pc2", "bvh", "gltf")

API = """
import sys
from pathlib import Path
from puppet.export import Outputs, export_take
from puppet.replay import open_take
take, out = sys.argv[1], Path(sys.argv[2])
rig, reader = open_take(take, None)
export_take(rig, reader, Outputs(**{fmt: out / name for fmt, name in %r.items()}), fps=30)
""" % (FORMATS,)


@pytest.fixture(scope="module")
def big_take(tmp_path_factory):
    """A take of 12 readings of the critter rig with 300 clusters and 30 extra weights."""
    folder = tmp_path_factory.mktemp("threads")
    text = BUILTIN_RIG.read_text().replace('name = "critter"', 'name = "critter_fine"')
    text = text.replace('mesh = "critter.npz"', f'mesh = "{BUILTIN_RIG.parent / "critter.npz"}"')
    text = re.sub(r"(?m)^clusters = \d+$", "clusters = 300", text)
    text = re.sub(r"(?m)^extra_weights = \d+$", "extra_weights = 30", text)
    (folder / "critter_fine.toml").write_text(text)
    rig = load_rig(folder / "critter_fine.toml")
    ids, k = rig.servo_map.ids, len(rig.servo_map)
    path = folder / "take.mcap"
    with TakeWriter(path, ids=[int(i) for i in ids], models=dict(rig.servo_map.models),
                    rig_map_text=text, calibration_text="", rig_name=rig.name) as writer:
        for i in range(12):
            ticks = (rig.servo_map.zero + 380 * np.sin(0.15 * i + np.arange(k))).astype(np.int32)
            writer.write(Reading(1_000_000_000 + round(i * 1e9 / 30), ids, ticks, np.ones(k, bool)))
    return path


def _env(threads: str | None, cache) -> dict:
    env = {name: value for name, value in os.environ.items() if name not in THREAD_VARIABLES}
    if threads is not None:
        env.update({name: threads for name in THREAD_VARIABLES})
    env["PUPPET_CACHE"] = str(cache)
    return env


def _outputs(folder) -> dict[str, bytes]:
    """{format: bytes} of one run's files; asserts that run computed its own precompute."""
    assert len(list((folder / "cache" / "fast").glob("*.npz"))) == 1
    return {fmt: (folder / FORMATS[fmt]).read_bytes() for fmt in COMPARED}


def _export_command(take, folder, threads):
    args = [arg for fmt, name in FORMATS.items() for arg in (f"--{fmt}", str(folder / name))]
    result = subprocess.run(["puppet", "export", str(take), *args], capture_output=True, text=True,
                            timeout=600, env=_env(threads, folder / "cache"))
    assert result.returncode == 0, result.stderr
    return _outputs(folder)


def _export_api(take, folder, threads):
    result = subprocess.run([sys.executable, "-c", API, str(take), str(folder)], capture_output=True,
                            text=True, timeout=600, env=_env(threads, folder / "cache"))
    assert result.returncode == 0, result.stderr
    return _outputs(folder)


def test_exports_are_byte_identical_for_every_thread_setting_and_entry_point(big_take, tmp_path,
                                                                             monkeypatch):
    runs = {}
    for threads in ("1", "2", None):
        folder = tmp_path / f"command-{threads}"
        folder.mkdir()
        runs[f"puppet export, threads {threads or 'unset'}"] = _export_command(big_take, folder, threads)
    folder = tmp_path / "api-unset"
    folder.mkdir()
    runs["API, threads unset"] = _export_api(big_take, folder, None)

    from puppet.export import Outputs, export_take
    from puppet.replay import open_take

    folder = tmp_path / "api-here"
    folder.mkdir()
    monkeypatch.setenv("PUPPET_CACHE", str(folder / "cache"))
    with threadpool_limits(2):  # as numpy starts on a machine of two or more cores
        rig, reader = open_take(big_take, None)
        export_take(rig, reader, Outputs(**{fmt: folder / name for fmt, name in FORMATS.items()}),
                    fps=30)
    runs["API in this process, 2 threads"] = _outputs(folder)

    reference = runs.pop("puppet export, threads 1")
    differing = {(run, fmt) for run, files in runs.items() for fmt in COMPARED
                 if files[fmt] != reference[fmt]}
    assert differing == set()
