"""Takes of two characters exported as docs/blender.md says, and what Blender shows of them.

Blender runs as the ``bpy`` module (Blender as a Python module, from PyPI; the test extras list
it) in a subprocess: ``docs/blender_check.py`` does every step of docs/blender.md and saves what
each step shows. The characters:

- critter: the built-in character (its mesh comes from an .npz, so the PC2 and the BVH go on the
  mesh of the exported .glb): tests/export/conftest.py's take and reference solve, at 24 fps;
- mare: the seamed, textured character of ``tests/rig/character.py``, its armature and mesh nodes moved,
  turned and scaled unevenly, exported at 30 fps (so a scene left at Blender's 24 fps would show).
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from puppet.rig import load_rig

HERE = Path(__file__).resolve().parent
CHECK_SCRIPT = HERE.parents[2] / "docs" / "blender_check.py"
#: Blender's importers turn puppet's +Y-up model frame to Blender's +Z up: (x, y, z) -> (x, -z, y).
Y_UP_TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def load_module(name: str, path: Path):
    """A test helper module by path (pytest runs with --import-mode=importlib)."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


character = load_module("blender_test_character", HERE.parents[1] / "rig" / "character.py")
blender = load_module("blender_test_run_bpy", HERE / "run_bpy.py")
export_data = load_module("blender_test_export_data", HERE.parent / "conftest.py")


@pytest.fixture(scope="session", autouse=True)
def needs_bpy():
    """Every test here runs Blender: skipped, saying why, where bpy is not installed."""
    reason = blender.bpy_missing()
    if reason:
        pytest.skip(reason)


@dataclass
class Shown:
    """One character's export and what Blender showed of it.

    expected: (N, n_file, 3) the solver's vertices of every frame, in the character file's vertex
        order, in Blender's world axes (what every step should show, up to skinning);
        rest_expected (n_file, 3) the rig's rest vertices the same way; rigid_skinning
        (N, n_file, 3) the same way, linear blend skinning with the file's 4 largest weights of
        the joints' rigid maps (rotation part and pivot of each FAST handle: what a BVH drives).
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
    rigid_skinning: np.ndarray
    diagonal: float
    fps: float
    frames: int
    report: dict
    steps: dict
    joint_names: tuple
    blender_output: str


STEP_FILES = {"gltf": "--glb", "pc2": "--pc2", "bvh": "--bvh", "usd": "--usd"}


def run_blender_check(folder: Path, fps: float, frames: int, files: dict,
                      character_file=None) -> tuple[dict, str]:
    """Run docs/blender_check.py on the files of an export ({format: path}, any of them):
    ({step: shown}, what it printed)."""
    saved = folder / "shown.npz"
    argv = [CHECK_SCRIPT, "--fps", f"{fps:g}", "--frames", str(frames), "--save", str(saved)]
    argv += [arg for fmt, path in files.items() for arg in (STEP_FILES[fmt], str(path))]
    if character_file is not None:
        argv += ["--character", str(character_file)]
    output = blender.run_bpy(*argv, cwd=folder)
    with np.load(saved) as data:
        meta = json.loads(str(data["meta"]))
        for key in data.files:
            if key != "meta":
                step, field = key.split(".")
                meta[step][field] = data[key]
    return meta, output


DOCS_FILES = {"gltf": "anim.glb", "usd": "anim.usdc", "bvh": "skeleton.bvh", "pc2": "mesh.pc2"}


def export(folder: Path, take: Path, fps: float, rig_file=None, names=DOCS_FILES,
           options=("--up", "z")) -> tuple[dict, dict]:
    """``puppet export`` as docs/blender.md writes it (names: {format: file name}): ({format:
    path}, its --json report)."""
    files = {fmt: folder / name for fmt, name in names.items()}
    argv = ["puppet", "export", str(take), "--fps", f"{fps:g}", *options, "--json"]
    argv += [arg for fmt, path in files.items() for arg in (f"--{fmt}", str(path))]
    if rig_file is not None:
        argv += ["--rig", str(rig_file)]
    result = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return files, json.loads(result.stdout.strip().splitlines()[-1])


def rigid_skinning(rig, Ts: np.ndarray) -> np.ndarray:
    """(N, n, 3) model-space linear blend skinning of the rig's rest vertices by each joint's
    rigid map P_j (``puppet.export.JointTransforms``) for every frame's T (N, 4m, 3), with each
    vertex's 4 largest weights renormalized (what a glTF skin holds)."""
    from puppet.export import JointTransforms
    from puppet.export.gltf import top_weights

    joints, weights = top_weights(rig.W, 4)
    maps = JointTransforms(rig.skeleton.heads)
    Vh = np.hstack([rig.V, np.ones((len(rig.V), 1))])
    out = []
    for T in Ts:
        P = maps.update(T).world  # (b, 3, 4)
        posed = np.einsum("bij,nj->nbi", P, Vh)  # every vertex by every joint
        out.append(np.einsum("nk,nki->ni", weights, np.take_along_axis(posed, joints[:, :, None], 1)))
    return np.array(out)


def shown_for(name, rig, take, folder, fps, reference, rig_file=None, character_file=None) -> Shown:
    files, report = export(folder, take, fps, rig_file)
    order = np.arange(len(rig.V)) if rig.source_index is None else np.asarray(rig.source_index)
    expected = reference.deformed[:, order] @ Y_UP_TO_BLENDER.T
    steps, output = run_blender_check(folder, fps, len(expected), files, character_file)
    rest = rig.V[order] @ Y_UP_TO_BLENDER.T
    rigid = rigid_skinning(rig, reference.T)[:, order] @ Y_UP_TO_BLENDER.T
    diagonal = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    return Shown(name, expected, rest, rigid, diagonal, fps, len(expected), report, steps,
                 tuple(rig.skeleton.names), output)


@pytest.fixture(scope="session")
def critter_shown(tmp_path_factory, critter, take30, fps, reference) -> Shown:
    return shown_for("critter", critter, take30, tmp_path_factory.mktemp("critter_blender"), fps,
                     reference)


@pytest.fixture(scope="session")
def mare_files(tmp_path_factory):
    """(folder, character .glb, rig file, take) of the transformed, seamed character."""
    folder = tmp_path_factory.mktemp("mare")
    glb = character.write(folder / "mare.glb", character.mare())
    rig_file = folder / "mare.toml"
    rig_file.write_text(character.mare_rig_text(glb.name))
    rig = load_rig(rig_file)
    take = export_data.write_take(folder / "mare.mcap", rig, readings=40)
    return folder, glb, rig_file, take


@pytest.fixture(scope="session")
def mare_shown(mare_files) -> Shown:
    folder, glb, rig_file, take = mare_files
    rig = load_rig(rig_file)
    reference = export_data.reference_solve(rig, take, fps=30.0)
    return shown_for("mare", rig, take, folder, 30.0, reference, rig_file, glb)


@pytest.fixture(scope="session")
def mare_usdz(mare_files, mare_shown) -> dict:
    """The USD step on the transformed character exported as a packaged .usdz."""
    folder, _, rig_file, take = mare_files
    folder = folder / "usdz"
    folder.mkdir()
    files, _ = export(folder, take, mare_shown.fps, rig_file, names={"usd": "anim.usdz"})
    steps, _ = run_blender_check(folder, mare_shown.fps, mare_shown.frames, files)
    return steps["usd"]


@pytest.fixture(scope="session")
def mare_model_space(mare_files, mare_shown) -> dict:
    """The PC2 step on the character's own import with a PC2 written ``--space model``."""
    folder, glb, rig_file, take = mare_files
    folder = folder / "model_space"
    folder.mkdir()
    files, _ = export(folder, take, mare_shown.fps, rig_file, names={"pc2": "model.pc2"},
                      options=("--up", "z", "--space", "model"))
    steps, _ = run_blender_check(folder, mare_shown.fps, mare_shown.frames, files, glb)
    return steps["pc2_source"]


@pytest.fixture(params=["critter", "mare"])
def shown(request) -> Shown:
    """Each character in turn."""
    return request.getfixturevalue(f"{request.param}_shown")
