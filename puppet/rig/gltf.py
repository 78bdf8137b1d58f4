"""glTF 2.0 skinned meshes (.glb and .gltf) via pygltflib.

What is read: one skin (the only one the meshes use, or the one chosen with ``skin=``) and every
node that has a mesh and that skin; every triangle primitive of those meshes (POSITION, indices,
all JOINTS_n/WEIGHTS_n sets); accessors with byteStride, normalized integers and sparse
substitution; the skin's joints, their node hierarchy and rest pose, and inverse bind matrices
(identity when absent). The rest of what the file holds for exports (vertex attributes,
primitives, materials and images, every node) is read into ``GltfCharacter.source``
(``puppet.rig.source_scene``).

Rest geometry: the rig's rest vertices are the glTF skinning formula evaluated at the nodes'
rest pose, ``v = Σ_j w_j G_j IBM_j v_mesh`` (equal to the mesh positions when the file's rest
pose is its bind pose). Bone j's pivot and frame are its joint node's rest global transform
(scale removed); its tip is its child joint (if exactly one) or pivot + frame y · length.
Weights of all sets are summed per joint and rows renormalized to 1.

Bounds (an error naming the file past them): files and the buffer files they name are regular
files (a FIFO or device is refused, never read) of at most MAX_FILE_BYTES; at most MAX_NODES
nodes and MAX_JOINTS joints per skin, counted in the JSON before anything else is parsed; at most
MAX_VERTICES vertices and MAX_WEIGHT_ENTRIES vertices x joints (the dense weight matrix); joint names of at most
MAX_NAME_LENGTH characters, valid Unicode (a lone surrogate is refused). Node transforms and
positions must be finite, and rest vertices and joints within COORD (+-1e6 model units);
the skinned meshes must hold at least one triangle. The node hierarchy is walked without
recursion (a chain of any depth within MAX_JOINTS reads).

Welding: copies of a vertex that the exporter split at seams (same position, same weights) are
welded into one (``puppet.rig.weld``); ``source_index`` maps the file's vertices to the welded
ones. Joints that no vertex follows are kept (the solver moves them rigidly with their
neighbours) and listed in ``unused_joints`` so commands can warn.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from puppet.rig.errors import RigError, check_regular_file
from puppet.rig.skeleton import Skeleton
from puppet.rig.solve_options import COORD
from puppet.rig.source_scene import SourceScene, read_source_scene
from puppet.rig.weight_check import normalize_weights
from puppet.rig.weld import weld_index, weld_mesh

COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16,
                    5125: np.uint32, 5126: np.float32}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
TRIANGLES = 4
GLB_MAGIC = b"glTF"
#: A joint whose weight never exceeds this influences no vertex.
UNUSED_WEIGHT = 1e-6
#: Joints of the skin read (each is a bone: a handle of every per-frame solve).
MAX_JOINTS = 2048
#: Vertices of the skinned meshes, in the file (before welding).
MAX_VERTICES = 1_000_000
#: Vertices x joints: the dense weight matrix (float64: 8 bytes each, 400 MB at the bound).
MAX_WEIGHT_ENTRIES = 50_000_000
#: Characters of a joint name.
MAX_NAME_LENGTH = 256
#: Bytes of a glTF file, or of one buffer file it names (read whole: a bound, not a tuning).
MAX_FILE_BYTES = 2 * 2**30
#: Nodes of the document (every joint is a node; 8 per joint leaves room for meshes, cameras,
#: lights and empties): counted in its JSON before the document is parsed into objects.
MAX_NODES = 8 * MAX_JOINTS


@dataclass
class GltfCharacter:
    """A skinned character read from a glTF file, welded.

    V:              (n, 3) float64 rest vertices (welded), F (f, 3) int32, W (n, bones) float64.
    skeleton:       bones = skin joints, reordered parents first.
    joint_nodes:    (bones,) the glTF node index of each bone.
    source_index:   (n_file,) int64: for each vertex of the file (primitives in order), its index
                    in ``V``; None when nothing was welded (the file's order is ``V``'s).
    file_vertices:  vertex count in the file (before welding).
    skin:           index of the skin read.
    unused_joints:  names of bones that no vertex follows (weight <= UNUSED_WEIGHT everywhere).
    source:         the file's look and place (``puppet.rig.source_scene.SourceScene``): vertex
                    attributes, primitives, materials, images, nodes; exports carry it.
    """

    V: np.ndarray
    F: np.ndarray
    W: np.ndarray
    skeleton: Skeleton
    joint_nodes: np.ndarray
    source_index: np.ndarray | None = None
    file_vertices: int = 0
    skin: int = 0
    unused_joints: tuple[str, ...] = ()
    source: SourceScene | None = None


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
                data = _read_bounded(self.path.parent / buf.uri, f"buffer file {buf.uri!r}",
                                     buf.byteLength, self.path, f"buffers[{index}].uri")
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


def _read_bounded(file: Path, what: str, length, path: Path, field: str) -> bytes:
    """The first ``length`` bytes (all when None) of a regular file of at most MAX_FILE_BYTES;
    RigError naming the glTF file and field otherwise (a FIFO or device is never read)."""
    import os
    import stat

    try:
        info = os.stat(file)
    except OSError as err:
        raise RigError(f"cannot read {what}: {err.strerror}", path=path, field=field) from None
    if not stat.S_ISREG(info.st_mode):
        raise RigError(f"{what} ({file}) is not a regular file (a FIFO, device or folder): "
                       "only regular files are read", path=path, field=field)
    if info.st_size > MAX_FILE_BYTES:
        raise RigError(f"{what} holds {info.st_size} bytes; at most {MAX_FILE_BYTES} are read",
                       path=path, field=field)
    try:
        with open(file, "rb") as handle:
            return handle.read(-1 if length is None else max(0, int(length)))
    except OSError as err:
        raise RigError(f"cannot read {what}: {err.strerror}", path=path, field=field) from None


def _check_counts(doc: dict, path: Path) -> None:
    """RigError past MAX_NODES nodes or MAX_JOINTS joints in a skin, from the document's JSON
    (before pygltflib turns every node into an object)."""
    nodes = doc.get("nodes")
    if isinstance(nodes, list) and len(nodes) > MAX_NODES:
        raise RigError(f"{len(nodes)} nodes; at most {MAX_NODES} are read", path=path,
                       field="nodes")
    skins = doc.get("skins")
    for index, skin in enumerate(skins if isinstance(skins, list) else []):
        joints = skin.get("joints") if isinstance(skin, dict) else None
        if isinstance(joints, list) and len(joints) > MAX_JOINTS:
            raise RigError(f"{len(joints)} joints; at most {MAX_JOINTS} are read", path=path,
                           field=f"skins[{index}].joints")


def _check_container(path: Path) -> None:
    """RigError unless the file is a glTF 2.0 binary (.glb) or JSON (.gltf) document."""
    import json
    import struct

    try:
        with open(path, "rb") as handle:
            head = handle.read(20)
            if head[:4] == GLB_MAGIC:
                if len(head) < 20:
                    raise RigError("not a glTF file: the binary header is cut short", path=path)
                version, _, json_length, json_type = struct.unpack_from("<IIII", head, 4)
                if version != 2:
                    raise RigError(f"glTF binary version {version}; only glTF 2.0 is read", path=path)
                if json_type != 0x4E4F534A:
                    raise RigError("not a glTF file: the first chunk is not JSON", path=path)
                raw = handle.read(json_length)
            elif path.suffix.lower() == ".glb":
                raise RigError(f"not a glTF binary: a .glb starts with 'glTF', this file starts "
                               f"with {head[:4]!r}", path=path)
            else:
                raw = head + handle.read()
    except OSError as err:
        raise RigError(f"cannot read: {err.strerror}", path=path) from err
    try:
        doc = json.loads(raw)
    except (ValueError, UnicodeDecodeError) as err:
        raise RigError(f"not a glTF file: its JSON does not parse ({err})", path=path) from err
    asset = doc.get("asset") if isinstance(doc, dict) else None
    if not isinstance(asset, dict) or "version" not in asset:
        raise RigError("not a glTF file: no 'asset' with a 'version'", path=path, field="asset")
    if not str(asset["version"]).startswith("2"):
        raise RigError(f"glTF version {asset['version']}; only glTF 2.0 is read", path=path,
                       field="asset.version")
    _check_counts(doc, path)


def _choose_skin(gltf, path: Path, skin: int | None) -> tuple[int, list[int]]:
    """(skin index, node indices that have a mesh and that skin)."""
    nodes = gltf.nodes or []
    skins = gltf.skins or []
    skinned = [i for i, n in enumerate(nodes) if n.mesh is not None and n.skin is not None]
    for i in skinned:
        if not 0 <= nodes[i].mesh < len(gltf.meshes or []) or not 0 <= nodes[i].skin < len(skins):
            raise RigError(f"mesh {nodes[i].mesh} or skin {nodes[i].skin} does not exist", path=path,
                           field=f"nodes[{i}]")
    used = sorted({nodes[i].skin for i in skinned})

    def named(k):
        return f"{k} ({skins[k].name!r})" if skins[k].name else str(k)

    if skin is not None:
        if not 0 <= skin < len(skins):
            raise RigError(f"skin {skin} does not exist: the file has {len(skins)} skin(s)", path=path,
                           field="skins")
        chosen = [i for i in skinned if nodes[i].skin == skin]
        if not chosen:
            raise RigError(f"no mesh uses skin {named(skin)}; skinned meshes use "
                           f"{', '.join(named(k) for k in used) or 'none'}", path=path, field="skins")
        return skin, chosen
    if not used:
        meshes = len(gltf.meshes or [])
        raise RigError(f"no skin: {meshes} mesh(es) and {len(skins)} skin(s), but no node has both a "
                       "mesh and a skin (export the mesh with its armature and skinning on)",
                       path=path, field="skins")
    if len(used) > 1:
        raise RigError(f"{len(used)} skins are used by meshes: {', '.join(named(k) for k in used)}; "
                       "choose one with --skin N (or 'skin = N' in the rig file)", path=path, field="skins")
    return used[0], [i for i in skinned if nodes[i].skin == used[0]]


def _read_meshes(gltf, acc: _Accessors, path: Path, mesh_nodes: list[int], joint_count: int):
    """(positions (n, 3), triangles (f, 3) int64, weights (n, joints)) of every triangle
    primitive of the meshes of ``mesh_nodes``, concatenated in order."""
    positions, triangles, weights = [], [], []
    offset = 0
    for node_index in mesh_nodes:
        mesh_index = gltf.nodes[node_index].mesh
        for p_index, prim in enumerate(gltf.meshes[mesh_index].primitives):
            where = f"meshes[{mesh_index}].primitives[{p_index}]"
            if (prim.mode if prim.mode is not None else TRIANGLES) != TRIANGLES:
                raise RigError(f"mode {prim.mode} is not triangles (4)", path=path, field=where)
            attributes = {k: v for k, v in vars(prim.attributes).items() if v is not None}
            if "POSITION" not in attributes:
                raise RigError("no POSITION attribute", path=path, field=where)
            P = acc.read(attributes["POSITION"], f"{where}.POSITION").astype(np.float64)
            if P.shape[1] != 3:
                raise RigError("POSITION must be VEC3", path=path, field=f"{where}.POSITION")
            n = len(P)
            if offset + n > MAX_VERTICES or (offset + n) * joint_count > MAX_WEIGHT_ENTRIES:
                raise RigError(f"too large: {offset + n} vertices so far with {joint_count} joints; "
                               f"at most {MAX_VERTICES} vertices and {MAX_WEIGHT_ENTRIES} vertices x "
                               "joints are read", path=path, field=f"{where}.POSITION")
            if not np.isfinite(P).all():
                raise RigError("a vertex position is not finite", path=path,
                               field=f"{where}.POSITION")
            if prim.indices is not None:
                idx = acc.read(prim.indices, f"{where}.indices", normalize=False).reshape(-1).astype(np.int64)
            else:
                idx = np.arange(n)
            if len(idx) % 3 or (len(idx) and (idx.min() < 0 or idx.max() >= n)):
                raise RigError(f"indices must be triples below {n}", path=path, field=f"{where}.indices")
            sets = sorted(int(k.split("_")[1]) for k in attributes if k.startswith("JOINTS_"))
            if not sets:
                raise RigError("no JOINTS_0/WEIGHTS_0 attributes (mesh is not skinned)", path=path, field=where)
            Wp = np.zeros((n, joint_count))
            for s in sets:
                if f"WEIGHTS_{s}" not in attributes:
                    raise RigError(f"JOINTS_{s} without WEIGHTS_{s}", path=path, field=where)
                J = acc.read(attributes[f"JOINTS_{s}"], f"{where}.JOINTS_{s}", normalize=False).astype(np.int64)
                Ws = acc.read(attributes[f"WEIGHTS_{s}"], f"{where}.WEIGHTS_{s}").astype(np.float64)
                if J.shape != (n, 4) or Ws.shape != (n, 4):
                    raise RigError(f"JOINTS_{s}/WEIGHTS_{s} must be VEC4 with {n} elements", path=path,
                                   field=where)
                used = Ws != 0
                if used.any() and (J[used].min() < 0 or J[used].max() >= joint_count):
                    raise RigError(f"joint index {int(J[used].max())} out of range: skin has {joint_count} "
                                   "joints", path=path, field=f"{where}.JOINTS_{s}")
                if (Ws < 0).any():
                    raise RigError("negative weight", path=path, field=f"{where}.WEIGHTS_{s}")
                np.add.at(Wp, (np.repeat(np.arange(n), 4)[used.reshape(-1)], J[used]), Ws[used])
            positions.append(P)
            triangles.append(idx.reshape(-1, 3) + offset)
            weights.append(Wp)
            offset += n
    if not positions or not sum(len(t) for t in triangles):
        raise RigError("the skinned meshes hold no triangles (a character needs a surface)",
                       path=path, field="meshes")
    return np.concatenate(positions), np.concatenate(triangles), np.concatenate(weights)


def _inverse_bind_matrices(skin, skin_index: int, acc: _Accessors, path: Path, names: list[str]) -> np.ndarray:
    """(joints, 4, 4) inverse bind matrices; RigError naming the joint of one that is not an
    invertible affine matrix."""
    joints = len(skin.joints)
    field = f"skins[{skin_index}].inverseBindMatrices"
    if skin.inverseBindMatrices is None:
        return np.tile(np.eye(4), (joints, 1, 1))
    ibm = acc.read(skin.inverseBindMatrices, field)
    if ibm.shape != (joints, 16):
        raise RigError(f"needs {joints} MAT4, got {ibm.shape}", path=path, field=field)
    ibm = ibm.reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major in the file
    for k, m in enumerate(ibm):
        where = f"{field}[{k}] (joint {names[k]!r})"
        if not np.isfinite(m).all():
            raise RigError("not finite", path=path, field=where)
        if np.abs(m[3] - [0, 0, 0, 1]).max() > 1e-6:
            raise RigError(f"not an affine matrix: last row {m[3].tolist()}", path=path, field=where)
        scale = max(float(np.abs(m[:3, :3]).max()), 1e-300)
        det = float(np.linalg.det(m[:3, :3]))
        if abs(det) <= 1e-9 * scale ** 3:
            raise RigError(f"not invertible (determinant {det:.3g}): the joint's bind pose is "
                           "degenerate (a zero scale?)", path=path, field=where)
    return ibm


def read_gltf(path, skin: int | None = None) -> GltfCharacter:
    """Read one skinned character of a .glb/.gltf file; errors name the file and the field.

    skin: index of the skin to read; None reads the only skin the file's meshes use (an error
    lists the skins when there are several).
    """
    import pygltflib

    path = Path(path)
    if not path.exists():
        raise RigError("glTF file not found", path=path)
    check_regular_file(path, "glTF file")
    if path.stat().st_size > MAX_FILE_BYTES:
        raise RigError(f"{path.stat().st_size} bytes; at most {MAX_FILE_BYTES} are read",
                       path=path)
    if path.suffix.lower() == ".glb" and path.is_file() and path.stat().st_size < 12:
        raise RigError(f"{path.stat().st_size} bytes: too short for a binary glTF (12-byte header)",
                       path=path)
    _check_container(path)
    try:
        gltf = pygltflib.GLTF2.load(str(path))
    except (ValueError, KeyError, TypeError, OSError) as err:
        raise RigError(f"not a readable glTF 2.0 file: {err}", path=path) from err
    if gltf is None:
        raise RigError("not a readable glTF 2.0 file", path=path)
    acc = _Accessors(gltf, path)
    nodes = gltf.nodes or []
    skin_index, mesh_nodes = _choose_skin(gltf, path, skin)
    skin_def = gltf.skins[skin_index]
    joints = list(skin_def.joints)
    if not joints or not all(0 <= j < len(nodes) for j in joints):
        raise RigError(f"joints {joints} must be node indices below {len(nodes)}", path=path,
                       field=f"skins[{skin_index}].joints")
    if len(set(joints)) != len(joints):
        raise RigError("a joint node is listed twice", path=path, field=f"skins[{skin_index}].joints")
    if len(joints) > MAX_JOINTS:
        raise RigError(f"{len(joints)} joints; at most {MAX_JOINTS} are read", path=path,
                       field=f"skins[{skin_index}].joints")
    joint_names = [_joint_name(nodes[j].name, k, j, path) for k, j in enumerate(joints)]

    V_mesh, F, W_raw = _read_meshes(gltf, acc, path, mesh_nodes, len(joints))
    W = normalize_weights(W_raw, path=path, field_name="WEIGHTS_n")

    # Rest pose of the node hierarchy.
    parent_node = {c: i for i, n in enumerate(nodes) for c in (n.children or [])
                   if isinstance(c, int)}
    G = _rest_globals(nodes, parent_node, joints, path)
    ibm = _inverse_bind_matrices(skin_def, skin_index, acc, path, joint_names)
    skinning = np.einsum("jab,jbc->jac", G, ibm)  # (joints, 4, 4)
    V_h = np.concatenate([V_mesh, np.ones((len(V_mesh), 1))], axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        V = np.einsum("nj,jab,nb->na", W, skinning[:, :3, :], V_h)
    if not np.isfinite(V).all():
        raise RigError("the rest pose puts vertices at infinity (huge node or bind transforms)",
                       path=path, field=f"skins[{skin_index}]")
    reach = max(float(np.abs(V).max()), float(np.abs(G[:, :3, 3]).max()))
    if not COORD.holds(reach):
        raise RigError(f"rest vertices or joints lie {reach:.3g} model units from the origin; "
                       f"coordinates must each be {COORD}", path=path, field=f"skins[{skin_index}]")

    skeleton, order = _skeleton(G, joints, parent_node, joint_names, V)
    W = W[:, order]
    source_index = weld_index(V_mesh, W)
    file_vertices = len(V)
    if int(source_index.max()) + 1 < file_vertices:
        V, F, W = weld_mesh(V, F, W, source_index)
    else:
        source_index = None
    unused = tuple(name for name, w in zip(skeleton.names, W.max(axis=0)) if w <= UNUSED_WEIGHT)
    joint_nodes = np.array([joints[k] for k in order])
    worlds = _rest_globals(nodes, parent_node, list(range(len(nodes))), path)  # checks every node
    source = read_source_scene(
        gltf, acc, path, locals_=np.array([_node_local(n) for n in nodes]), worlds=worlds,
        parent_node=parent_node,
        mesh_nodes=mesh_nodes, joints=joints,
        bone_of_joint={int(node): bone for bone, node in enumerate(joint_nodes)}, skin_index=skin_index)
    return GltfCharacter(V, F.astype(np.int32), W, skeleton, joint_nodes, source_index,
                         file_vertices, skin_index, unused, source)


def _joint_name(name, k: int, node: int, path: Path) -> str:
    """Joint k's name (node ``node``'s, or 'joint{k}'); RigError for one that cannot be written
    back (a lone surrogate is not Unicode text) or is longer than MAX_NAME_LENGTH."""
    if not name:
        return f"joint{k}"
    if not isinstance(name, str):
        raise RigError(f"name {name!r} is not a string", path=path, field=f"nodes[{node}].name")
    if len(name) > MAX_NAME_LENGTH:
        raise RigError(f"joint name of {len(name)} characters; at most {MAX_NAME_LENGTH}",
                       path=path, field=f"nodes[{node}].name")
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise RigError(f"joint name {ascii(name)} holds a lone surrogate: not Unicode text",
                       path=path, field=f"nodes[{node}].name") from None
    return name


def _rest_globals(nodes, parent_node: dict, joints: list[int], path: Path) -> np.ndarray:
    """(joints, 4, 4) rest global transforms of the joint nodes, walking up each node's
    ancestors without recursion (RigError naming the node for a cycle or a transform that is
    not finite)."""
    globals_: dict[int, np.ndarray] = {}
    for j in joints:
        chain, i, seen = [], j, set()
        while i is not None and i not in globals_:  # up to a known or a root node
            if i in seen:
                raise RigError("node hierarchy has a cycle", path=path, field=f"nodes[{i}]")
            seen.add(i)
            chain.append(i)
            i = parent_node.get(i)
        above = None if i is None else globals_[i]
        for i in reversed(chain):  # back down, parents first
            try:
                local = _node_local(nodes[i])
            except (TypeError, ValueError) as err:
                raise RigError(f"unusable transform: {err}", path=path,
                               field=f"nodes[{i}]") from None
            if not np.isfinite(local).all():
                raise RigError("transform is not finite (translation, rotation, scale or matrix)",
                               path=path, field=f"nodes[{i}]")
            with np.errstate(over="ignore", invalid="ignore"):
                above = local if above is None else above @ local
            if not np.isfinite(above).all():
                raise RigError("rest transform overflows (huge translations or scales above it)",
                               path=path, field=f"nodes[{i}]")
            globals_[i] = above
    return np.array([globals_[j] for j in joints])


def _skeleton(G: np.ndarray, joints: list[int], parent_node: dict, joint_names: list[str],
              V: np.ndarray) -> tuple[Skeleton, list[int]]:
    """The skeleton of the skin's joints (parents first) and the order: bone i = joint order[i].

    G: (joints, 4, 4) rest global transforms; joint parents are the nearest ancestor nodes that
    are joints; V (n, 3) sizes the tips of leaf bones.
    """
    joint_pos = {node_index: k for k, node_index in enumerate(joints)}

    def joint_parent(k):
        i = parent_node.get(joints[k])
        while i is not None and i not in joint_pos:
            i = parent_node.get(i)
        return -1 if i is None else joint_pos[i]

    parent_of = [joint_parent(k) for k in range(len(joints))]
    order: list[int] = []
    placed: set[int] = set()
    for k in range(len(joints)):  # each joint after its parent, without recursion
        chain = []
        while k >= 0 and k not in placed:
            chain.append(k)
            k = parent_of[k]
        for c in reversed(chain):
            placed.add(c)
            order.append(c)
    children: dict[int, list[int]] = {}
    for c, p in enumerate(parent_of):
        children.setdefault(p, []).append(c)
    new_index = {k: i for i, k in enumerate(order)}
    heads = G[order, :3, 3]
    frames = []
    for k in order:
        u, _, vt = np.linalg.svd(G[k, :3, :3])
        r = u @ vt
        if np.linalg.det(r) < 0:
            r = u @ np.diag([1, 1, -1]) @ vt
        frames.append(r)
    frames = np.array(frames)
    extent = float(np.linalg.norm(V.max(0) - V.min(0))) if len(V) else 1.0
    tails = []
    for i, k in enumerate(order):
        kids = children.get(k, [])
        if len(kids) == 1 and np.linalg.norm(G[kids[0], :3, 3] - heads[i]) > 1e-9:
            tails.append(G[kids[0], :3, 3])
        else:
            lengths = [np.linalg.norm(G[c, :3, 3] - heads[i]) for c in kids]
            length = max(lengths) if lengths and max(lengths) > 1e-9 else 0.05 * extent
            tails.append(heads[i] + frames[i][:, 1] * length)
    names, seen = [], set()
    for k in order:
        name = joint_names[k]
        while name in seen:
            name += "_"
        seen.add(name)
        names.append(name)
    parents = np.array([-1 if parent_of[k] < 0 else new_index[parent_of[k]] for k in order])
    return Skeleton(tuple(names), parents, heads, np.array(tails), frames), order


def external_files(path) -> list[Path]:
    """The files a .gltf/.glb character names by uri (buffers, images), resolved next to it;
    [] when it names none or cannot be read (reading it later says what is wrong)."""
    import json
    import struct

    import os
    import stat

    path = Path(path)
    try:
        info = os.stat(path)
        if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_FILE_BYTES:
            return []  # never read: loading it says what is wrong
        raw = path.read_bytes()
        if raw[:4] == GLB_MAGIC:
            length, = struct.unpack_from("<I", raw, 12)
            raw = raw[20:20 + length]
        doc = json.loads(raw)
        uris = [item.get("uri") for key in ("buffers", "images") for item in doc.get(key, [])
                if isinstance(item, dict)]
    except (OSError, ValueError, struct.error, AttributeError):
        return []
    return [path.parent / uri for uri in uris
            if isinstance(uri, str) and uri and not uri.startswith("data:")]
