"""USD export read back with usd-core: stage metadata, exact points per frame, every joint."""

import numpy as np
from pxr import Usd, UsdGeom, UsdSkel


def test_usd_points_are_the_solver_vertices_and_every_joint_is_animated(exported, critter,
                                                                         reference, fps):
    paths, report = exported
    stage = Usd.Stage.Open(str(paths["usd"]))
    N = len(reference.times_ns)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == fps
    assert stage.GetFramesPerSecond() == fps
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1.0, float(N))
    root = stage.GetDefaultPrim().GetPath()

    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(root.AppendChild("Mesh")))
    points = mesh.GetPointsAttr()
    assert points.GetTimeSamples() == [float(k) for k in range(1, N + 1)]
    for k in range(1, N + 1):  # frame k: time code k; the solver's vertices to float precision
        got = np.asarray(points.Get(Usd.TimeCode(k)), np.float64)
        np.testing.assert_allclose(got, reference.deformed[k - 1], rtol=0, atol=2e-6)
    faces = np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    np.testing.assert_array_equal(faces, critter.F)

    sk = critter.skeleton
    skeleton = UsdSkel.Skeleton(stage.GetPrimAtPath(root.AppendPath("Rig/Skeleton")))
    joints = list(skeleton.GetJointsAttr().Get())
    assert len(joints) == sk.bone_count
    assert [j.split("/")[-1] for j in joints] == list(sk.names)
    cache = UsdSkel.Cache()
    cache.Populate(UsdSkel.Root(stage.GetPrimAtPath(root.AppendChild("Rig"))),
                   Usd.TraverseInstanceProxies())
    query = cache.GetSkelQuery(skeleton)
    assert bool(query) and query.HasBindPose() and bool(query.GetAnimQuery())
    anim = query.GetAnimQuery()
    assert len(anim.GetJointOrder()) == sk.bone_count
    assert anim.GetJointTransformTimeSamples() == [float(k) for k in range(1, N + 1)]
    b = sk.bone_count
    full = critter.full_bones
    for k in (1, N // 2, N):
        world = np.array(query.ComputeJointSkelTransforms(Usd.TimeCode(k)))  # row-vector 4x4
        Tb = reference.T[k - 1].reshape(-1, 4, 3)[:b].astype(np.float64)
        pivots = np.einsum("bi,bij->bj", np.hstack([sk.heads, np.ones((b, 1))]), Tb)
        np.testing.assert_allclose(world[:, 3, :3], pivots, atol=2e-5)
        fk = critter.pose(reference.angles[k - 1])
        bind = np.array(skeleton.GetBindTransformsAttr().Get())
        skinning = np.linalg.inv(bind) @ world  # rest point (row) -> posed point
        np.testing.assert_allclose(np.swapaxes(skinning[full, :, :3], 1, 2), fk[full], atol=2e-5)
