"""Frame 1 of ``play`` and of every export is a converged pose: within 1e-4 of the bounding-box
diagonal of a converged solve of the same reading (it used to be 8 iterations from rest: 16 % of
the diagonal off on the critter holding one pose, a pop at frame 2)."""

import importlib.util
from pathlib import Path

import numpy as np
import pygltflib

from puppet.demo import Performance
from puppet.export import Outputs, SourceOrder, export_take
from puppet.reading import Reading
from puppet.replay import play_take
from puppet.rig import builtin
from puppet.take import TakeReader, TakeWriter

TOLERANCE = 1e-4  # of the rest bounding-box diagonal


def _readers_module():
    """tests/export/readers.py, the tests' readers of the exported files."""
    path = Path(__file__).resolve().parents[1] / "export" / "readers.py"
    spec = importlib.util.spec_from_file_location("first_frame_readers", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def held_take(path, rig, seconds=1.0, rate=30):
    """The critter holding one pose (the demo's pose at 0.7 s) for ``seconds``."""
    perf = Performance(rig)
    ids = rig.servo_map.ids
    ticks = np.array([perf.position(i, 0.7) for i in ids]).round().astype(np.int32)
    with TakeWriter(path, ids=[int(i) for i in ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name, overwrite=True) as w:
        for f in range(int(seconds * rate) + 1):
            w.write(Reading(1_000_000_000 + round(f * 1e9 / rate), ids, ticks, np.ones(len(ids), bool)))
    return path, ticks


def converged_T(rig, ticks) -> np.ndarray:
    """(4m, 3) float64: the reading solved far past convergence with the plain equations."""
    from puppet.loop.pipeline import model_for

    model = model_for(rig)
    pattern = rig.pattern()
    values = pattern.values()
    rig.fill_values(rig.servo_map.angles(ticks), values)
    T = model.rest_T()
    model.solver(pattern).solve(values, T, iterations=3000, accelerate=False)
    model.solver(pattern).solve(values, T, iterations=3000)
    return model, T.astype(np.float64)


class FirstFrame:
    """A per-frame sink of the solve (``play_take(solved=...)``) keeping frame 1's vertices."""

    def __init__(self):
        self.vertices = None

    def write(self, pipeline) -> None:
        if self.vertices is None:
            self.vertices = pipeline.deformed().copy()


def test_frame_one_of_play_and_every_export_is_converged(tmp_path):
    rig = builtin()
    take, ticks = held_take(tmp_path / "held.mcap", rig)
    model, T = converged_T(rig, ticks)
    diag = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    reference = model.deform(T)  # (n, 3)
    b = rig.skeleton.bone_count
    heads = np.hstack([rig.skeleton.heads, np.ones((b, 1))])
    pivots = np.einsum("bi,bij->bj", heads, T.reshape(-1, 4, 3)[:b])

    first = FirstFrame()
    play_take(rig, TakeReader(take), [], fps=30, size=(64, 48), solved=[first])
    assert np.linalg.norm(first.vertices - reference, axis=1).max() <= TOLERANCE * diag

    paths = {"gltf": tmp_path / "a.glb", "usd": tmp_path / "a.usdc", "pc2": tmp_path / "a.pc2",
             "bvh": tmp_path / "a.bvh"}
    export_take(rig, TakeReader(take), Outputs(**paths), fps=24)
    readers = _readers_module()
    mesh = SourceOrder(rig).take(reference)
    _, pc2 = readers.read_pc2(paths["pc2"])
    assert np.linalg.norm(pc2[0] - mesh, axis=1).max() <= TOLERANCE * diag

    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(paths["usd"]))
    points = UsdGeom.Mesh(stage.GetPrimAtPath(stage.GetDefaultPrim().GetPath().AppendChild("Mesh")))
    usd = np.asarray(points.GetPointsAttr().Get(Usd.TimeCode(1)), np.float64)
    assert np.linalg.norm(usd - mesh, axis=1).max() <= TOLERANCE * diag

    gltf_pivots, _ = readers.key_pivots(pygltflib.GLTF2().load_binary(str(paths["gltf"])), b)
    assert np.linalg.norm(gltf_pivots[0] - pivots, axis=1).max() <= TOLERANCE * diag
    bvh = readers.read_bvh(paths["bvh"].read_text())
    names, bvh_pivots = bvh.names, readers.pivots(bvh)
    order = [rig.skeleton.names.index(n) for n in names]
    assert np.linalg.norm(bvh_pivots[0] - pivots[order], axis=1).max() <= TOLERANCE * diag
