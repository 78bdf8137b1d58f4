"""Takes of two characters exported as docs/blender.md says, and what Blender shows of them.

Blender runs as the ``bpy`` module (Blender as a Python module, from PyPI; the test extras list
it) in a subprocess: ``docs/blender_check.py`` does every step of docs/blender.md and saves what
each step shows. The characters:

- critter: the built-in character (its mesh comes from an .npz, so the PC2 and the BVH go on the
  mesh of the exported .glb), the shared 24 fps export of tests/export/conftest.py's take;
- mare: the seamed, textured character of ``character.py``, its armature and mesh nodes moved,
  turned and scaled unevenly, exported at 30 fps (so a scene left at Blender's 24 fps would show).
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
CHECK_SCRIPT = HERE.parents[2] / "docs" / "blender_check.py"
#: Blender's importers turn puppet's +Y-up model frame to Blender's +Z up: (x, y, z) -> (x, -z, y).
Y_UP_TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
BLENDER_TIMEOUT_S = 900  # one subprocess does every step; about 10 s on a quiet machine


def load_module(name: str, path: Path):
    """A test helper module by path (pytest runs with --import-mode=importlib)."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


character = load_module("blender_test_character", HERE / "character.py")
export_data = load_module("blender_test_export_data", HERE.parent / "conftest.py")


def bpy_missing() -> str | None:
    """Why ``bpy`` cannot run here, or None."""
    if importlib.util.find_spec("bpy") is None:
        return (f"the bpy module (Blender as a Python module, PyPI) is not installed in this "
                f"Python {sys.version_info.major}.{sys.version_info.minor}: its wheels are for one "
                f"Python version (bpy 5.0: 3.11) and a few platforms; CI installs it with "
                f"pip install '.[test]'")
    return None


@dataclass
class Shown:
    """One character's export and what Blender showed of it.

    expected: (N, n_file, 3) the solver's vertices of every frame, in the character file's vertex
        order, in Blender's world axes (what every step should show, up to skinning);
        rest_expected (n_file, 3) the rig's rest vertices the same way.
    diagonal: rest bounding-box diagonal (model units), the yardstick of every % below.
    fps, frames: the export's rate and frame count; report: ``puppet export --json``'s report.
    steps: {step: {"vertices": (frames, n, 3) world vertices, "fps", "frame_start",
        "frame_end", ...}} as docs/blender_check.py saved them.
    joint_names: the rig's joint names (the character file's); blender_output: what
        docs/blender_check.py printed (one line per step).
    """

    name: str
    expected: np.ndarray
    rest_expected: np.ndarray
    diagonal: float
    fps: float
    frames: int
    report: dict
    steps: dict
    joint_names: tuple
    blender_output: str


def run_blender_check(folder: Path, fps: float, frames: int, files: dict, character_file=None) -> tuple[dict, str]:
    """Run docs/blender_check.py on the export in ``folder``: ({step: shown}, its output)."""
    saved = folder / "shown.npz"
    argv = [sys.executable, str(CHECK_SCRIPT), "--fps", f"{fps:g}", "--frames", str(frames),
            "--glb", str(files["gltf"]), "--pc2", str(files["pc2"]), "--bvh", str(files["bvh"]),
            "--usd", str(files["usd"]), "--save", str(saved)]
    if character_file is not None:
        argv += ["--character", str(character_file)]
    result = subprocess.run(argv, cwd=folder, capture_output=True, text=True, timeout=BLENDER_TIMEOUT_S)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
    with np.load(saved) as data:
        meta = json.loads(str(data["meta"]))
        for key in data.files:
            if key != "meta":
                step, field = key.split(".")
                meta[step][field] = data[key]
    return meta, result.stdout


def export(folder: Path, take: Path, fps: float, rig_file=None) -> tuple[dict, dict]:
    """``puppet export`` exactly as docs/blender.md writes it: ({format: path}, report)."""
    files = {"gltf": folder / "anim.glb", "usd": folder / "anim.usdc", "bvh": folder / "skeleton.bvh",
             "pc2": folder / "mesh.pc2"}
    argv = ["puppet", "export", str(take), "--fps", f"{fps:g}", "--gltf", str(files["gltf"]),
            "--usd", str(files["usd"]), "--bvh", str(files["bvh"]), "--pc2", str(files["pc2"]),
            "--up", "z", "--json"]
    if rig_file is not None:
        argv += ["--rig", str(rig_file)]
    result = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return files, json.loads(result.stdout.strip().splitlines()[-1])


def shown_for(name, rig, take, folder, fps, rig_file=None, character_file=None) -> Shown:
    reason = bpy_missing()
    if reason:
        pytest.skip(reason)
    files, report = export(folder, take, fps, rig_file)
    reference = export_data.reference_solve(rig, take, fps=fps)
    order = np.arange(len(rig.V)) if rig.source_index is None else np.asarray(rig.source_index)
    expected = reference.deformed[:, order] @ Y_UP_TO_BLENDER.T
    steps, output = run_blender_check(folder, fps, len(expected), files, character_file)
    rest = rig.V[order] @ Y_UP_TO_BLENDER.T
    return Shown(name, expected, rest, float(np.linalg.norm(rig.V.max(0) - rig.V.min(0))), fps,
                 len(expected), report, steps, tuple(rig.skeleton.names), output)


@pytest.fixture(scope="session")
def critter_shown(tmp_path_factory, critter, take30, fps) -> Shown:
    return shown_for("critter", critter, take30, tmp_path_factory.mktemp("critter_blender"), fps)


@pytest.fixture(scope="session")
def mare_files(tmp_path_factory):
    """(folder, character .glb, rig file, take) of the transformed, seamed character."""
    folder = tmp_path_factory.mktemp("mare")
    glb = character.write_glb(folder / "mare.glb")
    rig_file = folder / "mare.toml"
    rig_file.write_text(character.rig_text(glb.name))
    from puppet.rig import load_rig

    rig = load_rig(rig_file)
    take = export_data.write_take(folder / "mare.mcap", rig, readings=40)
    return folder, glb, rig_file, take


@pytest.fixture(scope="session")
def mare_shown(mare_files) -> Shown:
    from puppet.rig import load_rig

    folder, glb, rig_file, take = mare_files
    return shown_for("mare", load_rig(rig_file), take, folder, 30.0, rig_file, glb)


@pytest.fixture(params=["critter", "mare"])
def shown(request) -> Shown:
    """Each character in turn."""
    return request.getfixturevalue(f"{request.param}_shown")
