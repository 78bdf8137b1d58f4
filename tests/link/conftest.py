"""The live link's tests: a take of the built-in critter and ``puppet export --gltf`` of it."""

from __future__ import annotations

import importlib.util
import json
import subprocess
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
TAKE_FPS = 30.0


def load_module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


export_data = load_module("link_test_export_data", HERE.parent / "export" / "conftest.py")


@pytest.fixture(scope="session")
def critter():
    from puppet.rig import builtin

    return builtin()


@pytest.fixture(scope="session")
def take(tmp_path_factory, critter):
    return export_data.write_take(tmp_path_factory.mktemp("link") / "take.mcap", critter,
                                  readings=46)


@pytest.fixture(scope="session")
def exported(tmp_path_factory, take):
    """{'glb': path, 'report': dict} of ``puppet export TAKE --gltf`` at the take's rate."""
    folder = tmp_path_factory.mktemp("link_export")
    glb = folder / "anim.glb"
    done = subprocess.run(["puppet", "export", str(take), "--gltf", str(glb), "--fps",
                           f"{TAKE_FPS:g}", "--json"], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    return {"glb": glb, "report": json.loads(done.stdout.strip().splitlines()[-1])}


character = load_module("link_test_character", HERE.parent / "rig" / "character.py")


@pytest.fixture(scope="session")
def mare(tmp_path_factory):
    """The seamed character whose armature node is moved, turned and scaled unevenly
    (tests/rig/character.py): {'rig', 'rig_file', 'take', 'glb'} (its take's
    ``puppet export --gltf`` at the take's rate)."""
    from puppet.rig import load_rig

    folder = tmp_path_factory.mktemp("link_mare")
    character.write(folder / "mare.glb", character.mare())
    rig_file = folder / "mare.toml"
    rig_file.write_text(character.mare_rig_text("mare.glb"))
    rig = load_rig(rig_file)
    take = export_data.write_take(folder / "mare.mcap", rig, readings=30)
    glb = folder / "anim.glb"
    done = subprocess.run(["puppet", "export", str(take), "--rig", str(rig_file), "--gltf",
                           str(glb), "--fps", f"{TAKE_FPS:g}"], capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr
    return {"rig": rig, "rig_file": rig_file, "take": take, "glb": glb}
