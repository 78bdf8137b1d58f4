"""BVH of a take: the tests' BVH reader (readers.py) rebuilds every joint by forward kinematics and finds
puppet's skeleton, sensed and solved joints alike; unsafe joint names are mapped and reported."""

import importlib.util
from dataclasses import replace
from pathlib import Path

import numpy as np

from puppet.export import Outputs, export_take
from puppet.rig import Rig, ServoMap
from puppet.take import TakeReader


_spec = importlib.util.spec_from_file_location("export_bvh_take_readers", Path(__file__).with_name("readers.py"))
readers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readers)


def test_bvh_rebuilds_every_joint_of_the_solve(exported, critter, reference, fps):
    paths, report = exported
    bvh = readers.read_bvh(paths["bvh"].read_text())
    names, parents, offsets, frame_time, motion = bvh.names, bvh.parents, bvh.offsets, bvh.frame_time, bvh.motion
    sk = critter.skeleton
    assert sorted(names) == sorted(sk.names)
    assert abs(frame_time - 1 / fps) < 1e-9
    N = len(reference.times_ns)
    assert motion.shape[0] == N
    order = [sk.names.index(n) for n in names]  # file order -> bone index
    np.testing.assert_allclose(offsets[0], sk.heads[order[0]], atol=1e-6)
    for k in range(1, len(order)):  # offsets from the rig's rest pivots
        expected = sk.heads[order[k]] - sk.heads[order[parents[k]]]
        np.testing.assert_allclose(offsets[k], expected, atol=1e-6)
    b = sk.bone_count
    full = set(critter.full_bones.tolist())
    relative = set(critter.relative_bones.tolist())
    assert full and relative
    for f in range(N):
        pos, rot = readers.forward_kinematics(bvh, f)
        Tb = reference.T[f].reshape(-1, 4, 3)[:b].astype(np.float64)
        pivots = np.einsum("bi,bij->bj", np.hstack([sk.heads, np.ones((b, 1))]), Tb)
        np.testing.assert_allclose(pos, pivots[order], atol=2e-5)  # sensed and solved joints
        fk = critter.pose(reference.angles[f])
        joint_rotations = sk.joint_rotations(reference.angles[f])  # model space, per bone
        for k, j in enumerate(order):
            if j in full:  # sensed joints: exactly the forward kinematics of the servo angles
                np.testing.assert_allclose(rot[k], fk[j, :, :3], atol=2e-5)
            if j in relative:  # sensed below a solved joint: turned by its servos from its parent
                local = rot[parents[k]].T @ rot[k]
                np.testing.assert_allclose(local, joint_rotations[j], atol=2e-5)
    assert report.bvh_stretch_max_pct is not None


def test_joint_names_keep_punctuation_and_lose_whitespace(tmp_path, critter, take30):
    names = ["ear L" if n == "ear_L" else "ear.R (left?)" if n == "ear_R" else
             "tail.été" if n == "tail1" else n for n in critter.skeleton.names]
    rig = Rig(name=critter.name, V=critter.V, F=critter.F,
              skeleton=replace(critter.skeleton, names=tuple(names), joints=()), W=critter.W,
              servo_map=ServoMap(critter.servo_map.servos), calibration=critter.calibration,
              solver_options=critter.solver_options, pins=critter.pins, fixed=critter.fixed)
    out = tmp_path / "named.bvh"
    report = export_take(rig, TakeReader(take30), Outputs(bvh=out), fps=10)
    assert report.renamed == {"bvh": {"ear L": "ear_L", "ear.R (left?)": "ear.R_(left?)",
                                      "tail.été": "tail.ete"}}
    assert "bvh: joint 'ear L' is named 'ear_L' (the format's naming rule)" in report.text()
    file_names = readers.read_bvh(out.read_text()).names
    assert {"ear_L", "ear.R_(left?)", "tail.ete"} <= set(file_names)
    assert sorted(file_names) == sorted(report.renamed["bvh"].get(n, n) for n in names)
