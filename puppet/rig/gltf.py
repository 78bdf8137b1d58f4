"""glTF 2.0 skinned meshes (.glb and .gltf) via pygltflib.

What is read: the first node that has both a mesh and a skin; every triangle primitive of that
mesh (POSITION, indices, all JOINTS_n/WEIGHTS_n sets); accessors with byteStride, normalized
integers and sparse substitution; the skin's joints, their node hierarchy and rest pose, and
inverse bind matrices (identity when absent).

Rest geometry: the rig's rest vertices are the glTF skinning formula evaluated at the nodes'
rest pose, ``v = Σ_j w_j G_j IBM_j v_mesh`` (equal to the mesh positions when the file's rest
pose is its bind pose). Bone j's pivot and frame are its joint node's rest global transform
(scale removed); its tip is its child joint (if exactly one) or pivot + frame y · length.
Weights of all sets are summed per joint and rows renormalized to 1.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from puppet.rig.errors import RigError
from puppet.rig.skeleton import Skeleton
from puppet.rig.weight_check import normalize_weights

COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16,
                    5125: np.uint32, 5126: np.float32}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
TRIANGLES = 4


@dataclass
class GltfCharacter:
    """V (n, 3) float64, F (f, 3) int32, W (n, bones) float64, skeleton (bones = skin joints,
    reordered parents-first), and joint_nodes (bones,) the glTF node index of each bone."""

    V: np.ndarray
    F: np.ndarray
    W: np.ndarray
    skeleton: Skeleton
    joint_nodes: np.ndarray


class _Accessors:
    """Decodes accessors of one glTF document into float64 or integer arrays."""

    def __init__(self, gltf, path: Path) -> None:
        self.gltf, self.path = gltf, path
        self.buffers: dict[int, bytes] = {}

    def fail(self, message: str, field: str):
        raise RigError(message, path=self.path, field=field)

    def buffer(self, index: int) -> bytes:
        if index not in self.buffers:
            if not 0 <= index < len(self.gltf.buffers):
                self.fail(f"buffer {index} does not exist", f"buffers[{index}]")
            buf = self.gltf.buffers[index]
            if buf.uri is None:
                data = self.gltf.binary_blob()
                if data is None:
                    self.fail("buffer has no uri and the file has no binary chunk", f"buffers[{index}]")
            elif buf.uri.startswith("data:"):
                try:
                    data = base64.b64decode(buf.uri.split(",", 1)[1])
                except (ValueError, IndexError) as err:
                    self.fail(f"bad data uri: {err}", f"buffers[{index}].uri")
            else:
                try:
                    data = (self.path.parent / buf.uri).read_bytes()
                except OSError as err:
                    self.fail(f"cannot read {buf.uri!r}: {err.strerror}", f"buffers[{index}].uri")
            if buf.byteLength is not None and len(data) < buf.byteLength:
                self.fail(f"buffer holds {len(data)} bytes, byteLength says {buf.byteLength}",
                          f"buffers[{index}]")
            self.buffers[index] = bytes(data)
        return self.buffers[index]

    def _view(self, view_index: int, offset: int, count: int, dtype, width: int, field: str) -> np.ndarray:
        """(count, width) elements from a bufferView, honouring byteStride."""
        if not 0 <= view_index < len(self.gltf.bufferViews):
            self.fail(f"bufferView {view_index} does not exist", field)
        view = self.gltf.bufferViews[view_index]
        data = self.buffer(view.buffer)
        start = (view.byteOffset or 0) + (offset or 0)
        itemsize = np.dtype(dtype).itemsize
        element = itemsize * width
        stride = view.byteStride or element
        if stride < element:
            self.fail(f"byteStride {stride} is smaller than one element ({element} bytes)",
                      f"bufferViews[{view_index}].byteStride")
        needed = (count - 1) * stride + element if count else 0
        view_end = (view.byteOffset or 0) + view.byteLength
        if start + needed > view_end or view_end > len(data):
            self.fail(f"reads {needed} bytes at offset {start}, past the end of bufferView "
                      f"{view_index} or its buffer", field)
        if count == 0:
            return np.zeros((0, width), dtype)
        out = np.ndarray((count, width), np.dtype(dtype).newbyteorder("<"), data, start,
                         (stride, itemsize))
        return out.astype(dtype)

    def read(self, index, field: str, *, normalize: bool = True) -> np.ndarray:
        """Accessor ``index`` as (count, components); normalized integers become floats."""
        field = f"{field} (accessor {index})"
        if index is None or not 0 <= index < len(self.gltf.accessors):
            self.fail(f"accessor {index} does not exist", field)
        acc = self.gltf.accessors[index]
        if acc.componentType not in COMPONENT_DTYPES:
            self.fail(f"unknown componentType {acc.componentType}", field)
        if acc.type not in TYPE_SIZES:
            self.fail(f"unknown type {acc.type!r}", field)
        dtype = COMPONENT_DTYPES[acc.componentType]
        width = TYPE_SIZES[acc.type]
        if acc.bufferView is None:
            values = np.zeros((acc.count, width), dtype)
        else:
            values = self._view(acc.bufferView, acc.byteOffset, acc.count, dtype, width, field)
        if acc.sparse is not None and acc.sparse.count:
            sp = acc.sparse
            if sp.indices.componentType not in (5121, 5123, 5125):
                self.fail(f"sparse indices componentType {sp.indices.componentType}", field + " sparse")
            idx = self._view(sp.indices.bufferView, sp.indices.byteOffset, sp.count,
                             COMPONENT_DTYPES[sp.indices.componentType], 1, field + " sparse.indices")[:, 0]
            if idx.size and idx.max() >= acc.count:
                self.fail(f"sparse index {int(idx.max())} >= count {acc.count}", field + " sparse.indices")
            values = values.copy()
            values[idx.astype(np.int64)] = self._view(sp.values.bufferView, sp.values.byteOffset, sp.count,
                                                      dtype, width, field + " sparse.values")
        if acc.normalized and normalize and dtype is not np.float32:
            info = np.iinfo(dtype)
            values = values.astype(np.float64) / info.max
            if info.min < 0:
                values = np.maximum(values, -1.0)
        return values


def _node_local(node) -> np.ndarray:
    """(4, 4) local transform of a node (matrix, else T·R·S)."""
    if node.matrix is not None and len(node.matrix) == 16:
        return np.array(node.matrix, float).reshape(4, 4).T  # glTF matrices are column-major
    m = np.eye(4)
    if node.rotation is not None:
        x, y, z, w = node.rotation
        m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    if node.scale is not None:
        m[:3, :3] = m[:3, :3] * np.asarray(node.scale, float)[None, :]
    if node.translation is not None:
        m[:3, 3] = node.translation
    return m


def read_gltf(path) -> GltfCharacter:
    """Read the first skinned mesh of a .glb/.gltf file; errors name the file and the field."""
    import pygltflib

    path = Path(path)
    if not path.exists():
        raise RigError("glTF file not found", path=path)
    if path.suffix.lower() == ".glb" and path.is_file() and path.stat().st_size < 12:
        raise RigError(f"{path.stat().st_size} bytes: too short for a binary glTF (12-byte header)",
                       path=path)
    try:
        gltf = pygltflib.GLTF2.load(str(path))
    except (ValueError, KeyError, TypeError, OSError) as err:
        raise RigError(f"not a readable glTF 2.0 file: {err}", path=path) from err
    if gltf is None:
        raise RigError("not a readable glTF 2.0 file", path=path)
    acc = _Accessors(gltf, path)
    nodes = gltf.nodes or []
    skinned = [i for i, n in enumerate(nodes) if n.mesh is not None and n.skin is not None]
    if not skinned:
        raise RigError("no node has both a mesh and a skin", path=path, field="nodes")
    node = nodes[skinned[0]]
    if not 0 <= node.mesh < len(gltf.meshes or []) or not 0 <= node.skin < len(gltf.skins or []):
        raise RigError(f"mesh {node.mesh} or skin {node.skin} does not exist", path=path,
                       field=f"nodes[{skinned[0]}]")
    skin = gltf.skins[node.skin]
    joints = list(skin.joints)
    if not joints or not all(0 <= j < len(nodes) for j in joints):
        raise RigError(f"joints {joints} must be node indices below {len(nodes)}", path=path,
                       field=f"skins[{node.skin}].joints")
    if len(set(joints)) != len(joints):
        raise RigError("a joint node is listed twice", path=path, field=f"skins[{node.skin}].joints")

    # Geometry and weights of every triangle primitive.
    positions, triangles, weights = [], [], []
    offset = 0
    for p_index, prim in enumerate(gltf.meshes[node.mesh].primitives):
        where = f"meshes[{node.mesh}].primitives[{p_index}]"
        if (prim.mode if prim.mode is not None else TRIANGLES) != TRIANGLES:
            raise RigError(f"mode {prim.mode} is not triangles (4)", path=path, field=where)
        attributes = {k: v for k, v in vars(prim.attributes).items() if v is not None}
        if "POSITION" not in attributes:
            raise RigError("no POSITION attribute", path=path, field=where)
        P = acc.read(attributes["POSITION"], f"{where}.POSITION").astype(np.float64)
        if P.shape[1] != 3:
            raise RigError("POSITION must be VEC3", path=path, field=f"{where}.POSITION")
        n = len(P)
        if prim.indices is not None:
            idx = acc.read(prim.indices, f"{where}.indices", normalize=False).reshape(-1).astype(np.int64)
        else:
            idx = np.arange(n)
        if len(idx) % 3 or (len(idx) and (idx.min() < 0 or idx.max() >= n)):
            raise RigError(f"indices must be triples below {n}", path=path, field=f"{where}.indices")
        sets = sorted(int(k.split("_")[1]) for k in attributes if k.startswith("JOINTS_"))
        if not sets:
            raise RigError("no JOINTS_0/WEIGHTS_0 attributes (mesh is not skinned)", path=path, field=where)
        Wp = np.zeros((n, len(joints)))
        for s in sets:
            if f"WEIGHTS_{s}" not in attributes:
                raise RigError(f"JOINTS_{s} without WEIGHTS_{s}", path=path, field=where)
            J = acc.read(attributes[f"JOINTS_{s}"], f"{where}.JOINTS_{s}", normalize=False).astype(np.int64)
            Ws = acc.read(attributes[f"WEIGHTS_{s}"], f"{where}.WEIGHTS_{s}").astype(np.float64)
            if J.shape != (n, 4) or Ws.shape != (n, 4):
                raise RigError(f"JOINTS_{s}/WEIGHTS_{s} must be VEC4 with {n} elements", path=path, field=where)
            used = Ws != 0
            if used.any() and (J[used].min() < 0 or J[used].max() >= len(joints)):
                raise RigError(f"joint index {int(J[used].max())} out of range: skin has {len(joints)} joints",
                               path=path, field=f"{where}.JOINTS_{s}")
            if (Ws < 0).any():
                raise RigError("negative weight", path=path, field=f"{where}.WEIGHTS_{s}")
            np.add.at(Wp, (np.repeat(np.arange(n), 4)[used.reshape(-1)], J[used]), Ws[used])
        positions.append(P)
        triangles.append(idx.reshape(-1, 3) + offset)
        weights.append(Wp)
        offset += n
    V_mesh = np.concatenate(positions)
    F = np.concatenate(triangles).astype(np.int32)
    W = normalize_weights(np.concatenate(weights), path=path, field_name="WEIGHTS_n")

    # Rest pose of the node hierarchy.
    parent_node = {c: i for i, n in enumerate(nodes) for c in (n.children or [])}
    globals_: dict[int, np.ndarray] = {}

    def global_of(i, depth=0):
        if depth > len(nodes):
            raise RigError("node hierarchy has a cycle", path=path, field=f"nodes[{i}]")
        if i not in globals_:
            local = _node_local(nodes[i])
            p = parent_node.get(i)
            globals_[i] = local if p is None else global_of(p, depth + 1) @ local
        return globals_[i]

    if skin.inverseBindMatrices is not None:
        ibm = acc.read(skin.inverseBindMatrices, f"skins[{node.skin}].inverseBindMatrices")
        if ibm.shape != (len(joints), 16):
            raise RigError(f"needs {len(joints)} MAT4, got {ibm.shape}", path=path,
                           field=f"skins[{node.skin}].inverseBindMatrices")
        ibm = ibm.reshape(-1, 4, 4).transpose(0, 2, 1)
    else:
        ibm = np.tile(np.eye(4), (len(joints), 1, 1))
    G = np.array([global_of(j) for j in joints])
    skinning = np.einsum("jab,jbc->jac", G, ibm)  # (joints, 4, 4)
    V_h = np.concatenate([V_mesh, np.ones((len(V_mesh), 1))], axis=1)
    V = np.einsum("nj,jab,nb->na", W, skinning[:, :3, :], V_h)

    # Skeleton: joint parents = nearest ancestor that is a joint; order parents first.
    joint_pos = {node_index: k for k, node_index in enumerate(joints)}

    def joint_parent(k):
        i = parent_node.get(joints[k])
        while i is not None and i not in joint_pos:
            i = parent_node.get(i)
        return -1 if i is None else joint_pos[i]

    parent_of = [joint_parent(k) for k in range(len(joints))]
    order: list[int] = []

    def place(k):
        if k in order:
            return
        if parent_of[k] >= 0:
            place(parent_of[k])
        order.append(k)

    for k in range(len(joints)):
        place(k)
    new_index = {k: i for i, k in enumerate(order)}
    heads = G[order, :3, 3]
    frames = []
    for k in order:
        m = G[k, :3, :3]
        u, _, vt = np.linalg.svd(m)
        r = u @ vt
        if np.linalg.det(r) < 0:
            r = u @ np.diag([1, 1, -1]) @ vt
        frames.append(r)
    frames = np.array(frames)
    extent = float(np.linalg.norm(V.max(0) - V.min(0))) if len(V) else 1.0
    tails = []
    for i, k in enumerate(order):
        kids = [c for c in range(len(joints)) if parent_of[c] == k]
        if len(kids) == 1 and np.linalg.norm(G[kids[0], :3, 3] - heads[i]) > 1e-9:
            tails.append(G[kids[0], :3, 3])
        else:
            lengths = [np.linalg.norm(G[c, :3, 3] - heads[i]) for c in kids]
            length = max(lengths) if lengths and max(lengths) > 1e-9 else 0.05 * extent
            tails.append(heads[i] + frames[i][:, 1] * length)
    names, seen = [], set()
    for k in order:
        name = nodes[joints[k]].name or f"joint{k}"
        while name in seen:
            name += "_"
        seen.add(name)
        names.append(name)
    parents = np.array([-1 if parent_of[k] < 0 else new_index[parent_of[k]] for k in order])
    skeleton = Skeleton(tuple(names), parents, heads, np.array(tails), frames)
    return GltfCharacter(V, F, W[:, order], skeleton, np.array([joints[k] for k in order]))
