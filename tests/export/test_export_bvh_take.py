"""BVH of a take: a reader written here rebuilds every joint by forward kinematics and finds
puppet's skeleton, sensed and solved joints alike; unsafe joint names are mapped and reported."""

from dataclasses import replace

import numpy as np

from puppet.export import Outputs, export_take
from puppet.rig import Rig, ServoMap
from puppet.take import TakeReader


def elementary(axis, degrees):
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def read_bvh(text):
    """(names, parents, offsets, channels per joint, frame time, motion (N, values))."""
    tokens = text.split()
    names, parents, offsets, channels, stack = [], [], [], [], []
    i = 1
    while tokens[i] != "MOTION":
        t = tokens[i]
        if t in ("ROOT", "JOINT"):
            names.append(tokens[i + 1])
            parents.append(stack[-1] if stack else -1)
            offsets.append([float(x) for x in tokens[i + 4:i + 7]])
            count = int(tokens[i + 8])
            channels.append(tokens[i + 9:i + 9 + count])
            stack.append(len(names) - 1)
            i += 9 + count
        elif t == "End":
            i += 8  # End Site { OFFSET x y z }
        elif t == "}":
            stack.pop()
            i += 1
        else:
            raise AssertionError(f"unexpected {t!r}")
    frames, frame_time = int(tokens[i + 2]), float(tokens[i + 5])
    motion = np.array(tokens[i + 6:], float).reshape(frames, -1)
    return names, parents, np.array(offsets), channels, frame_time, motion


def forward_kinematics(parents, offsets, channels, values):
    """World positions (b, 3) and rotations (b, 3, 3) of one frame of motion values."""
    b = len(parents)
    pos, rot = np.zeros((b, 3)), np.zeros((b, 3, 3))
    col = 0
    for j in range(b):
        local_t, local_r = offsets[j].copy(), np.eye(3)
        for name in channels[j]:
            v = values[col]
            col += 1
            if name.endswith("position"):
                local_t["XYZ".index(name[0])] = v
            else:
                local_r = local_r @ elementary(name[0], v)
        p = parents[j]
        if p < 0:
            pos[j], rot[j] = local_t, local_r
        else:
            pos[j] = pos[p] + rot[p] @ local_t
            rot[j] = rot[p] @ local_r
    return pos, rot


def test_bvh_rebuilds_every_joint_of_the_solve(exported, critter, reference, fps):
    paths, report = exported
    names, parents, offsets, channels, frame_time, motion = read_bvh(paths["bvh"].read_text())
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
        pos, rot = forward_kinematics(parents, offsets, channels, motion[f])
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
    file_names = read_bvh(out.read_text())[0]
    assert {"ear_L", "ear.R_(left?)", "tail.ete"} <= set(file_names)
    assert sorted(file_names) == sorted(report.renamed["bvh"].get(n, n) for n in names)
