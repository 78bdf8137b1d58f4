"""A small closed test character written to disk in every test that needs one: a capped
8-sided tube along +Y (OBJ), a three-bone chain (TGF, 1-based), weights (DMAT)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from puppet.rig.tgf_dmat import write_dmat


def tube(levels=7, sides=8, height=3.0, radius=0.4):
    """Closed tube: (V (n,3), F (f,3)) outward-facing."""
    V = [[0, 0, 0]]
    for k in range(levels):
        for s in range(sides):
            a = 2 * np.pi * s / sides
            V.append([radius * np.cos(a), height * k / (levels - 1), radius * np.sin(a)])
    V.append([0, height, 0])
    V = np.array(V, float)
    F = []
    ring = lambda k, s: 1 + k * sides + s % sides
    for s in range(sides):
        F.append([0, ring(0, s), ring(0, s + 1)])
        F.append([len(V) - 1, ring(levels - 1, s + 1), ring(levels - 1, s)])
        for k in range(levels - 1):
            F.append([ring(k, s), ring(k + 1, s), ring(k + 1, s + 1)])
            F.append([ring(k, s), ring(k + 1, s + 1), ring(k, s + 1)])
    F = np.array(F)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() < 0:
        F = F[:, ::-1]
    return V, F


def tube_weights(V):
    """Hat functions of height for bones [0.1,1], [1,2], [2,2.9] (rows sum to 1)."""
    y = V[:, 1]
    centers = np.array([0.55, 1.5, 2.45])
    W = np.clip(1 - np.abs(y[:, None] - centers[None, :]), 0, None) + 1e-3
    return W / W.sum(axis=1, keepdims=True)


TGF = """1 0 0.1 0
2 0 1 0
3 0 2 0
4 0 2.9 0
#
1 2
2 3
3 4
"""

RIG_TOML = """name = "tube"
mesh = "tube.obj"
skeleton = "tube.tgf"
weights = "tube.dmat"
calibration = "tube.calibration.toml"

[solver]
clusters = 12
extra_weights = 2
energy = "spokes"

[[servo]]
id = 3
model = "XL330-M288"
joint = "bone1"
axis = "z"
zero_ticks = 2000
limits_deg = [-90, 90]

[[servo]]
id = 5
model = "XL430-W250"
joint = "bone3"
axis = [1, 0, 0]
order = 1
sign = -1
gear = 2.0
limits_deg = [-45, 45]

[[servo]]
id = 6
model = "XM430-W350"
joint = "bone3"
axis = "-y"
order = 2

[[pin]]
vertex = 0
"""


def write_obj(path, V, F):
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in V] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    path.write_text("# test tube\n" + "\n".join(lines) + "\n")


@pytest.fixture
def tube_rig_dir(tmp_path):
    """Folder with tube.obj, tube.tgf, tube.dmat and tube.toml (servos 3, 5, 6)."""
    V, F = tube()
    write_obj(tmp_path / "tube.obj", V, F)
    (tmp_path / "tube.tgf").write_text(TGF)
    write_dmat(tmp_path / "tube.dmat", tube_weights(V))
    (tmp_path / "tube.toml").write_text(RIG_TOML)
    return tmp_path


@pytest.fixture(scope="session")
def character():
    """The shared skinned glTF test character (module ``tests/rig/character.py``)."""
    spec = importlib.util.spec_from_file_location("rig_test_character", Path(__file__).with_name("character.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
