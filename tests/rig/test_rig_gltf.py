"""glTF 2.0 skins written in the test with pygltflib: strided, sparse and normalized accessors,
two JOINTS/WEIGHTS sets, inverse bind matrices, joint hierarchy, .glb and .gltf."""

import base64

import numpy as np
import pygltflib as g
import pytest

from puppet.rig import RigError, load_rig
from puppet.rig.gltf import read_gltf

POSITIONS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0], [1, 2, 0]], np.float32)
SPARSE_VERTEX, SPARSE_VALUE = 2, np.array([-0.5, 1.0, 0.25], np.float32)
TRIANGLES = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4]], np.uint16)
# JOINTS_0 (ubyte) with normalized-ubyte WEIGHTS_0, and JOINTS_1 (ushort) with float WEIGHTS_1.
JOINTS0 = np.array([[0, 1, 0, 0]] * 6, np.uint8)
WEIGHTS0 = np.array([[255, 0, 0, 0], [200, 55, 0, 0], [100, 100, 0, 0], [0, 255, 0, 0],
                     [0, 51, 0, 0], [0, 0, 0, 0]], np.uint8)
JOINTS1 = np.array([[2, 0, 0, 0]] * 6, np.uint16)
WEIGHTS1 = np.array([[0, 0, 0, 0], [0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0, 0, 0], [0.8, 0, 0, 0],
                     [1.0, 0, 0, 0]], np.float32)
# Skin joints listed child-first: [hand, root, arm] (nodes 2, 0, 1).
SKIN_JOINTS = [2, 0, 1]


def expected_weights():
    """Per skin joint (hand, root, arm) weights, summed over both sets and renormalized."""
    W = np.zeros((6, 3))
    for j, w in ((JOINTS0, WEIGHTS0.astype(float) / 255), (JOINTS1, WEIGHTS1.astype(float))):
        for v in range(6):
            for k in range(4):
                W[v, j[v, k]] += w[v, k]
    return W / W.sum(axis=1, keepdims=True)


def build(with_ibm=True, bad_joint=False):
    """A GLTF2 document and its binary buffer."""
    blob = bytearray()

    def add(data: bytes, align=4):
        while len(blob) % align:
            blob.append(0)
        offset = len(blob)
        blob.extend(data)
        return offset

    views, accessors = [], []

    def view(data, stride=None):
        views.append(g.BufferView(buffer=0, byteOffset=add(data), byteLength=len(data), byteStride=stride))
        return len(views) - 1

    def accessor(**kw):
        accessors.append(g.Accessor(**kw))
        return len(accessors) - 1

    # POSITION interleaved with a dummy normal: byteStride 24, position at offset 0.
    wrong = POSITIONS.copy()
    wrong[SPARSE_VERTEX] = [9, 9, 9]
    interleaved = np.concatenate([wrong, np.ones_like(wrong)], axis=1).astype(np.float32)
    pos_view = view(interleaved.tobytes(), stride=24)
    sparse = g.Sparse(count=1,
                      indices=g.AccessorSparseIndices(bufferView=view(np.array([SPARSE_VERTEX], np.uint32).tobytes()),
                                                      componentType=g.UNSIGNED_INT),
                      values=g.AccessorSparseValues(bufferView=view(SPARSE_VALUE.tobytes())))
    pos = accessor(bufferView=pos_view, componentType=g.FLOAT, count=6, type=g.VEC3, sparse=sparse,
                   min=[-0.5, 0, 0], max=[1, 2, 0.25])
    normal = accessor(bufferView=pos_view, byteOffset=12, componentType=g.FLOAT, count=6, type=g.VEC3)
    idx = accessor(bufferView=view(TRIANGLES.tobytes()), componentType=g.UNSIGNED_SHORT, count=12, type=g.SCALAR)
    joints0 = JOINTS0.copy()
    if bad_joint:
        joints0[3, 1] = 7
    j0 = accessor(bufferView=view(joints0.tobytes()), componentType=g.UNSIGNED_BYTE, count=6, type=g.VEC4)
    w0 = accessor(bufferView=view(WEIGHTS0.tobytes()), componentType=g.UNSIGNED_BYTE, normalized=True,
                  count=6, type=g.VEC4)
    j1 = accessor(bufferView=view(JOINTS1.tobytes()), componentType=g.UNSIGNED_SHORT, count=6, type=g.VEC4)
    w1 = accessor(bufferView=view(WEIGHTS1.tobytes()), componentType=g.FLOAT, count=6, type=g.VEC4)
    attributes = g.Attributes(POSITION=pos, NORMAL=normal, JOINTS_0=j0, WEIGHTS_0=w0)
    attributes.JOINTS_1, attributes.WEIGHTS_1 = j1, w1

    globals_ = {0: np.eye(4), 1: np.eye(4), 2: np.eye(4)}
    globals_[1][:3, 3] = [0, 1, 0]
    globals_[2][:3, 3] = [0, 2, 0]
    skin = g.Skin(joints=SKIN_JOINTS)
    if with_ibm:
        ibm = np.array([np.linalg.inv(globals_[n]).T.reshape(-1) for n in SKIN_JOINTS], np.float32)
        skin.inverseBindMatrices = accessor(bufferView=view(ibm.tobytes()), componentType=g.FLOAT,
                                            count=3, type=g.MAT4)
    nodes = [g.Node(name="root", children=[1]),
             g.Node(name="arm", translation=[0, 1, 0], children=[2]),
             g.Node(name="hand", translation=[0, 1, 0]),
             g.Node(name="body", mesh=0, skin=0)]
    doc = g.GLTF2(scene=0, scenes=[g.Scene(nodes=[0, 3])], nodes=nodes, skins=[skin],
                  meshes=[g.Mesh(primitives=[g.Primitive(attributes=attributes, indices=idx)])],
                  accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))])
    return doc, bytes(blob)


def save_glb(doc, blob, path):
    doc.set_binary_blob(blob)
    doc.save_binary(str(path))
    return path


def save_gltf(doc, blob, path):
    doc.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    doc.save_json(str(path))
    return path


@pytest.mark.parametrize("save", [save_glb, save_gltf])
def test_skinned_gltf_round_trip(tmp_path, save):
    doc, blob = build()
    path = save(doc, blob, tmp_path / ("c.glb" if save is save_glb else "c.gltf"))
    c = read_gltf(path)
    expected_v = POSITIONS.astype(float).copy()
    expected_v[SPARSE_VERTEX] = SPARSE_VALUE
    np.testing.assert_allclose(c.V, expected_v, atol=1e-6)
    np.testing.assert_array_equal(c.F, TRIANGLES)
    # bones reordered parents first: root, arm, hand; weight columns follow.
    assert c.skeleton.names == ("root", "arm", "hand")
    np.testing.assert_array_equal(c.skeleton.parents, [-1, 0, 1])
    np.testing.assert_array_equal(c.joint_nodes, [0, 1, 2])
    np.testing.assert_allclose(c.skeleton.heads, [[0, 0, 0], [0, 1, 0], [0, 2, 0]], atol=1e-12)
    np.testing.assert_allclose(c.skeleton.tails[:2], [[0, 1, 0], [0, 2, 0]], atol=1e-12)
    W = expected_weights()[:, [1, 2, 0]]
    np.testing.assert_allclose(c.W, W, atol=1e-12)
    np.testing.assert_allclose(c.W.sum(axis=1), 1)


def test_missing_inverse_bind_matrices_mean_identity(tmp_path):
    doc, blob = build(with_ibm=False)
    c = read_gltf(save_glb(doc, blob, tmp_path / "n.glb"))
    # identity IBMs: each joint's rest transform (a translation by its head) moves its share.
    expected_v = POSITIONS.astype(float).copy()
    expected_v[SPARSE_VERTEX] = SPARSE_VALUE
    expected_v = expected_v + c.W @ c.skeleton.heads
    np.testing.assert_allclose(c.V, expected_v, atol=1e-6)


def test_load_rig_on_glb_has_no_servos(tmp_path):
    doc, blob = build()
    rig = load_rig(save_glb(doc, blob, tmp_path / "c.glb"))
    assert len(rig.servo_map) == 0
    assert rig.bone_kinds()["free"] == ["root", "arm", "hand"]
    assert rig.check_weights().ok


def test_joint_index_out_of_range_names_the_accessor(tmp_path):
    doc, blob = build(bad_joint=True)
    path = save_glb(doc, blob, tmp_path / "bad.glb")
    with pytest.raises(RigError, match=r"bad.glb: meshes\[0\].primitives\[0\].JOINTS_0: joint index 7 out of range"):
        read_gltf(path)


def test_truncated_buffer_view_names_the_field(tmp_path):
    doc, blob = build()
    doc.accessors[0].count = 600
    path = save_glb(doc, blob, tmp_path / "short.glb")
    with pytest.raises(RigError, match=r"short.glb: meshes\[0\].primitives\[0\].POSITION \(accessor 0\): reads"):
        read_gltf(path)


def test_missing_file(tmp_path):
    with pytest.raises(RigError, match="glTF file not found"):
        read_gltf(tmp_path / "none.glb")
