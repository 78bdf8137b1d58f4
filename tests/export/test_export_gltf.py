"""glTF export read back with pygltflib: every joint animated, key times, skin, and how far the
file's own skinning is from the FAST mesh."""

import importlib.util
from pathlib import Path

import numpy as np
import pygltflib

_spec = importlib.util.spec_from_file_location("export_gltf_readers", Path(__file__).with_name("readers.py"))
readers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readers)
accessor, trs, worlds = readers.accessor, readers.trs, readers.worlds


def test_gltf_has_every_joint_animated_and_its_skin(exported, critter, reference, fps):
    paths, report = exported
    gltf = pygltflib.GLTF2().load_binary(str(paths["gltf"]))
    sk = critter.skeleton
    b = sk.bone_count
    skin = gltf.skins[0]
    assert skin.joints == list(range(b))
    assert [gltf.nodes[j].name for j in skin.joints] == list(sk.names)
    assert len(gltf.animations) == 1
    anim = gltf.animations[0]
    targets = [(c.target.node, c.target.path) for c in anim.channels]
    assert len(targets) == len(set(targets)) == 2 * b
    assert set(targets) == {(j, p) for j in range(b) for p in ("translation", "rotation")}
    N = len(reference.times_ns)
    assert report.frames == N
    for sampler in anim.samplers:
        times = accessor(gltf, sampler.input)
        np.testing.assert_allclose(times, np.arange(1, N + 1) / fps, rtol=1e-6)  # frame k at k/fps
        assert len(accessor(gltf, sampler.output)) == N

    # The mesh at rest, and a skin that reproduces it at rest (IBM = inverse rest world).
    prim = gltf.meshes[gltf.nodes[b].mesh].primitives[0]
    assert gltf.nodes[b].skin == 0
    np.testing.assert_allclose(accessor(gltf, prim.attributes.POSITION), critter.V, atol=1e-6)
    joints = accessor(gltf, prim.attributes.JOINTS_0).astype(int)
    weights = accessor(gltf, prim.attributes.WEIGHTS_0).astype(np.float64)
    np.testing.assert_allclose(weights.sum(1), 1.0, atol=1e-6)
    assert joints.max() < b and (weights >= 0).all()
    ibm = accessor(gltf, skin.inverseBindMatrices).reshape(b, 4, 4).transpose(0, 2, 1)
    rest = worlds(gltf, {j: trs(gltf.nodes[j].translation, gltf.nodes[j].rotation)
                         for j in range(b)})
    np.testing.assert_allclose(rest @ ibm, np.tile(np.eye(4), (b, 1, 1)), atol=1e-5)
    np.testing.assert_allclose(rest[:, :3, 3], sk.heads, atol=1e-6)

    # Every frame: joints where the solve puts them, sensed joints exactly on forward kinematics,
    # and linear blend skinning with the file's weights measured against the FAST mesh.
    keys = {(c.target.node, c.target.path): accessor(gltf, anim.samplers[c.sampler].output)
            for c in anim.channels}
    V = np.hstack([critter.V, np.ones((len(critter.V), 1))])
    diagonal = np.linalg.norm(critter.V.max(0) - critter.V.min(0))
    full = critter.full_bones
    errors = []
    for f in range(N):
        world = worlds(gltf, {j: trs(keys[j, "translation"][f], keys[j, "rotation"][f])
                              for j in range(b)})
        skinning = world @ ibm  # rest points -> posed points, per joint
        Tb = reference.T[f].reshape(-1, 4, 3)[:b].astype(np.float64)
        pivots = np.einsum("bi,bij->bj", np.hstack([sk.heads, np.ones((b, 1))]), Tb)
        np.testing.assert_allclose(world[:, :3, 3], pivots, atol=2e-5)
        fk = critter.pose(reference.angles[f])
        np.testing.assert_allclose(skinning[full, :3, :], fk[full], atol=2e-5)
        posed = np.einsum("nk,nkij,nj->ni", weights, skinning[joints][:, :, :3, :], V)
        errors.append(np.linalg.norm(posed - reference.deformed[f], axis=1))
    errors = np.array(errors)
    rms = 100 * np.sqrt((errors ** 2).mean()) / diagonal
    worst = 100 * errors.max() / diagonal
    print(f"\nglTF skeleton (LBS, file's weights) vs FAST mesh over {N} frames: "
          f"RMS {rms:.3f} %, max {worst:.3f} % of the bbox diagonal")
    assert abs(rms - report.lbs_rms_pct) < 1e-3 and abs(worst - report.lbs_max_pct) < 1e-3
    assert rms < 1.0 and worst < 4.0  # measured 0.44 % / 2.2 % on this take
