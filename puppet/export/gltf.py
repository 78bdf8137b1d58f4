"""glTF 2.0 binary (.glb): the character with its skin and one animation of every joint.

Layout of the file written, for a rig read from a glTF file (``Rig.source``, a SourceScene):
  nodes          the source file's nodes, same order, names, hierarchy and transforms (TRS or
                 matrix as written); joints keep their rest TRS and are animated; the skinned
                 mesh nodes keep theirs; other meshes, cameras and lights are left out (their
                 nodes stay as empties).
  skin 0         the rig's joints; inverseBindMatrices = inverse rest world of each joint times
                 the (first) mesh node's world, as Blender writes them.
  meshes         one per skinned mesh node, the source's primitives with their own indices and
                 materials; POSITION (rest vertices in the mesh node's space), NORMAL, TANGENT,
                 every TEXCOORD_n and COLOR_n of the source, JOINTS_n / WEIGHTS_n. The file's
                 vertex order and count are the source's (seam copies included): a PC2 fits both.
  materials      the source's, with their textures, samplers and images (embedded); a texture
                 whose image could not be read is left out, its materials plain.
For any other rig (the built-in critter, OBJ/PLY) the same code writes the plain case:
  nodes 0..b-1   the skeleton's joints (bone order, parents first); rest TRS from the rig's rest
                 pivots and frames; node b: the skinned mesh (identity transform).
  skin 0         joints 0..b-1; inverseBindMatrices = inverse rest world transform of each joint.
  mesh 0         one triangle primitive: POSITION, NORMAL, indices, JOINTS_n / WEIGHTS_n
                 (``influences`` per vertex, 4 per set; the largest weights, renormalized).
  animation 0    per joint one translation and one rotation channel (LINEAR): frame k (k = 1..N)
                 at k / fps seconds, so Blender's importer (frame = time · scene fps) puts frame 1
                 on scene frame 1 when the scene runs at fps. A key on every frame (one shared
                 key-time accessor), or with a key tolerance the keys that reproduce each channel
                 within it (``puppet.export.key_reduction``; LINEAR, which Blender plays as written).
  extras         the scene's and the animation's: {"puppet_fps", "puppet_frame_start": 1,
                 "puppet_frame_end": N}. Blender 5.0's importer turns the scene's into custom
                 properties of the scene (``import_scene_extras``, on by default) and changes
                 neither the scene's rate nor its range: set the scene's fps before importing,
                 then the range, e.g. (Python console) ``s = bpy.context.scene; s.frame_start,
                 s.frame_end = s["puppet_frame_start"], s["puppet_frame_end"]`` (or the action's
                 ``frame_range``, which is 1..N at the right fps).
Joints under a node with a non-uniform scale and a rotation cannot follow a rigid motion exactly
with translation and rotation keys; their keys keep the pivots exact and take the nearest
rotation, and ``written`` holds what the file reproduces (the export reports its skinning error).

Keys are the joints' parent-relative transforms of the rigid world maps P_j given per frame
(see ``puppet.export.joint_transforms``): posed world of joint j = P_j ∘ G_j (G_j its rest world).
Quaternions are kept on one hemisphere from key to key, so interpolation takes the short way.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib

from puppet.export.errors import ExportError
from puppet.export.key_reduction import reduce_curve
from puppet.export.joint_transforms import (compose, local_transforms, matrix_to_quaternion,
                                            polar_rotations, rest_globals)
from puppet.export.writer import ExportWriter
from puppet.rig.source_scene import SourceNode, SourcePrimitive, SourceScene

FLOAT, UINT8, UINT16, UINT32 = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


def top_weights(W: np.ndarray, influences: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``influences`` largest weights of each row of W (n, b), renormalized.

    Returns joints (n, influences) int64 sorted by weight (largest first; unused slots joint 0,
    weight 0) and weights (n, influences) float32 summing to one per row.
    """
    W = np.asarray(W, np.float64)
    n, b = W.shape
    k = min(influences, b)
    order = np.argsort(-W, axis=1, kind="stable")[:, :k]
    w = np.take_along_axis(W, order, axis=1)
    w = np.where(w > 0, w, 0.0)
    total = w.sum(1, keepdims=True)
    if (total <= 0).any():
        raise ExportError("weights", f"vertex {int(np.flatnonzero(total[:, 0] <= 0)[0])} has no weight")
    w = (w / total).astype(np.float32)
    w[:, 0] += np.float32(1.0) - w.sum(1, dtype=np.float32)  # float32 rows sum to one
    joints = np.where(w > 0, order, 0)
    if k < influences:
        joints = np.hstack([joints, np.zeros((n, influences - k), np.int64)])
        w = np.hstack([w, np.zeros((n, influences - k), np.float32)])
    return joints.astype(np.int64), w


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n, 3) float32 area-weighted unit vertex normals (+Y for unreferenced vertices)."""
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V, dtype=np.float64)
    for c in range(3):
        np.add.at(N, F[:, c], cross)
    length = np.linalg.norm(N, axis=1, keepdims=True)
    N = np.where(length > 0, N / np.where(length > 0, length, 1.0), [0.0, 1.0, 0.0])
    return N.astype(np.float32)


def _column_major(M: np.ndarray) -> np.ndarray:
    """(b, 3, 4) affine -> (b, 16) float32 column-major 4x4."""
    out = np.zeros((len(M), 4, 4))
    out[:, :3, :] = M
    out[:, 3, 3] = 1.0
    return np.swapaxes(out, 1, 2).reshape(len(M), 16).astype(np.float32)


class _Blob:
    """The binary chunk under construction: one buffer, one bufferView per accessor."""

    def __init__(self, gltf: pygltflib.GLTF2):
        self.gltf = gltf
        self.parts: list[bytes] = []
        self.size = 0

    def view(self, raw: bytes, target=None) -> int:
        """A bufferView of raw bytes (padded to 4); returns its index."""
        self.gltf.bufferViews.append(pygltflib.BufferView(
            buffer=0, byteOffset=self.size, byteLength=len(raw), target=target))
        self.parts.append(raw)
        self.size += len(raw)
        pad = (-self.size) % 4
        if pad:
            self.parts.append(b"\0" * pad)
            self.size += pad
        return len(self.gltf.bufferViews) - 1

    def add(self, array: np.ndarray, component: int, kind: str, *, target=None,
            minmax: bool = False) -> int:
        data = np.ascontiguousarray(array)
        view = self.view(data.tobytes(), target)
        rows = data.reshape(len(data), -1)
        accessor = pygltflib.Accessor(bufferView=view, componentType=component, count=len(data),
                                      type=kind)
        if minmax:
            accessor.min = [float(x) for x in rows.min(0)]
            accessor.max = [float(x) for x in rows.max(0)]
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def plain_scene(names, parents, rest: np.ndarray, n: int, F: np.ndarray, name: str) -> SourceScene:
    """The SourceScene of a rig that has none (not read from glTF): nodes 0..b-1 the joints
    (rest TRS from rest (b, 3, 4) rigid world transforms), node b the mesh (identity), one
    primitive of n vertices with triangles F (f, 3), no attributes or materials."""
    parents = np.asarray(parents, np.int64)
    local = local_transforms(rest, parents)
    q = matrix_to_quaternion(local[:, :, :3])
    nodes = []
    for j in range(len(parents)):
        L, G = np.eye(4), np.eye(4)
        L[:3] = local[j]
        G[:3] = rest[j]
        nodes.append(SourceNode(name=str(names[j]), parent=int(parents[j]),
                                children=[int(c) for c in np.flatnonzero(parents == j)],
                                translation=[float(x) for x in local[j, :, 3]],
                                rotation=[float(x) for x in q[j]], scale=None, matrix=None,
                                local=L, world=G, joint=j))
    nodes.append(SourceNode(name=name, parent=-1, children=[], translation=None, rotation=None,
                            scale=None, matrix=None, local=np.eye(4), world=np.eye(4), mesh=0))
    roots = [int(r) for r in np.flatnonzero(parents < 0)]
    primitive = SourcePrimitive(0, n, np.asarray(F, np.int64).reshape(-1), None, ())
    return SourceScene(path=Path(name), nodes=nodes, roots=roots + [len(parents)],
                       mesh_nodes=[len(parents)], mesh_names=[name], primitives=[[primitive]],
                       skeleton_node=roots[0] if len(roots) == 1 else None)


def _node_trs(node: SourceNode) -> tuple[list, list, list]:
    """(translation, rotation xyzw, scale) of a node: as written, or from its matrix."""
    if node.matrix is None:
        return (node.translation or [0.0, 0.0, 0.0], node.rotation or [0.0, 0.0, 0.0, 1.0],
                node.scale or [1.0, 1.0, 1.0])
    M = node.local[:3, :3]
    R = polar_rotations(M[None])[0]
    scale = np.einsum("ij,ij->j", R, M)  # diag(Rᵀ M)
    return ([float(x) for x in node.local[:3, 3]], [float(x) for x in matrix_to_quaternion(R)],
            [float(x) for x in scale])


def _texture_refs(value, remap: dict[int, int]):
    """A copy of a material dict whose texture references (``...Texture: {index}``) follow
    ``remap`` (old texture index -> new); references to textures not in it are dropped."""
    if isinstance(value, list):
        return [_texture_refs(v, remap) for v in value]
    if not isinstance(value, dict):
        return value
    out = {}
    for key, v in value.items():
        if key.endswith("Texture") and isinstance(v, dict) and "index" in v:
            if v["index"] not in remap:
                continue
            v = dict(v, index=remap[v["index"]])
        out[key] = _texture_refs(v, remap)
    return out


def _extension_names(value, found: set[str]) -> set[str]:
    """Names of every extension used in a JSON value (its ``extensions`` dicts' keys)."""
    if isinstance(value, dict):
        for key, v in value.items():
            if key == "extensions" and isinstance(v, dict):
                found.update(v)
            _extension_names(v, found)
    elif isinstance(value, list):
        for v in value:
            _extension_names(v, found)
    return found


def _similarity(M: np.ndarray, tolerance: float = 1e-9) -> bool:
    """Whether a (3, 3) linear map is a rotation times a uniform scale (Mᵀ M = c² I)."""
    G = M.T @ M
    c2 = float(np.trace(G)) / 3.0
    return c2 > 0 and bool(np.abs(G - c2 * np.eye(3)).max() <= tolerance * c2)


class GltfWriter(ExportWriter):
    """Collects one animation key per frame; ``close()`` writes the .glb in one piece.

    path:       output .glb file (written only by close()).
    names:      b joint names; parents (b,) int (-1 for roots, parents before children).
    heads:      (b, 3) rest pivots; frames (b, 3, 3) rest frames (columns = local axes).
    V:          (n, 3) rest vertices (model frame) in the file's order; F (f, 3) triangles into V.
    W:          (n, b) bone weights in the same vertex order.
    fps:        frames per second of the keys.
    influences: weights kept per vertex (a multiple of 4: one JOINTS_n/WEIGHTS_n set per 4).
    name:       name of the mesh, its node and the animation.
    source:     the character file's SourceScene (``Rig.source``): its nodes, primitives,
                attributes and materials are written (V must be in its vertex order); None: the
                plain layout (module docstring).
    keys_deg:   None: a key on every frame; else rotation keys reduced to this tolerance, degrees
                (``puppet.export.key_reduction``). keys_units: the same for translations, model
                units (None: every frame). forced_frames: (K,) 0-based frames that are keys on every
                channel whatever the tolerance (a shot's key poses, ``Playback.key_frames``).
    Fields: joints (n, influences) int64 and weights (n, influences) float32: the skin as written;
    keys_kept {joint name: {"translation": keys, "rotation": keys}} once closed; node_of_joint
    (b,) the node of each joint; written (b, 3, 4): after each write(), the rigid maps of rest
    points that the file's keys at that frame reproduce (the world given, up to the nearest
    rotation under non-uniformly scaled nodes); warnings: what could not be written.
    """

    close_on_error = False  # the .glb is written in one piece: an error inside `with` writes none

    def __init__(self, path, *, names, parents, heads, frames, V, F, W, fps: float,
                 influences: int = 4, name: str = "character", keys_deg: float | None = None,
                 keys_units: float | None = None, source: SourceScene | None = None,
                 forced_frames=(), sync: dict | None = None):
        self.path = Path(path)
        self.sync = dict(sync or {})  # puppet.export.sync.sync_fields: written into the extras
        if influences < 4 or influences % 4:
            raise ExportError(self.path, f"influences must be a multiple of 4, got {influences}")
        self.names = [str(n) for n in names]
        self.parents = np.asarray(parents, np.int64)
        self.b = len(self.names)
        if self.b > 65535:
            raise ExportError(self.path, f"{self.b} joints: glTF joint indices hold at most 65535")
        self.rest = rest_globals(np.asarray(heads, np.float64), np.asarray(frames, np.float64))
        self.V = np.asarray(V, np.float64)
        self.F = np.asarray(F, np.int64)
        self.fps = float(fps)
        self.name = name
        self.keys_deg, self.keys_units = keys_deg, keys_units
        self.forced_frames = np.asarray(forced_frames, np.int64)
        self.keys_kept: dict[str, dict[str, int]] = {}
        self.joints, self.weights = top_weights(W, influences)
        self.scene = source if source is not None else plain_scene(
            self.names, self.parents, self.rest, len(self.V), self.F, name)
        self._layout()
        self.written = np.zeros((self.b, 3, 4))
        self.written[:, :, :3] = np.eye(3)
        self.warnings: list[str] = []
        self._translations: list[np.ndarray] = []
        self._rotations: list[np.ndarray] = []
        self._previous_q = None
        self._lbs = None
        self._closed = False

    def _layout(self) -> None:
        """Where each joint sits in the node hierarchy, fixed once.

        node_of_joint (b,): its node. bind (b, 4, 4): its rest world. mesh_world (4, 4): the
        (first) mesh node's world. up_joint (b,): the nearest joint above its node (-1: none);
        above (b, 4, 4): its parent node's rest world relative to that joint (or the parent
        node's world; identity for a root node). node_scale (b, 3): the node's own scale.
        exact: every joint's parent node is a similarity at rest (its keys can follow any rigid
        motion exactly). levels: the joints in one group when exact, else grouped by depth below
        the first joint above them (parents first).
        """
        scene, b = self.scene, self.b
        by_bone = {n.joint: i for i, n in enumerate(scene.nodes) if n.joint >= 0}
        missing = [self.names[j] for j in range(b) if j not in by_bone]
        if missing:
            raise ExportError(self.path, f"joints {missing} have no node in {scene.path}")
        self.node_of_joint = np.array([by_bone[j] for j in range(b)], np.int64)
        self.bind = scene.joint_worlds(self.node_of_joint)
        self.mesh_world = scene.nodes[scene.mesh_nodes[0]].world
        self.up_joint = np.full(b, -1, np.int64)
        self.above = np.tile(np.eye(4), (b, 1, 1))
        self.node_scale = np.ones((b, 3))
        depth = np.zeros(b, np.int64)
        for j in range(b):  # bones are parents first: a joint above is placed before
            node = scene.nodes[self.node_of_joint[j]]
            self.node_scale[j] = _node_trs(node)[2]
            parent = node.parent
            if parent < 0:
                continue
            i = parent
            while i >= 0 and scene.nodes[i].joint < 0:
                i = scene.nodes[i].parent
            if i >= 0:
                up = scene.nodes[i].joint
                self.up_joint[j] = up
                self.above[j] = np.linalg.solve(self.bind[up], scene.nodes[parent].world)
                depth[j] = depth[up] + 1
            else:
                self.above[j] = scene.nodes[parent].world
        parent_linear = [np.eye(3) if scene.nodes[n].parent < 0 else
                         scene.nodes[scene.nodes[n].parent].world[:3, :3] for n in self.node_of_joint]
        self.exact = all(_similarity(M) for M in parent_linear)
        self.levels = ([np.arange(b)] if self.exact else
                       [np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1)])
        self._world4 = np.tile(np.eye(4), (b, 1, 1))
        self._posed = np.tile(np.eye(4), (b, 1, 1))
        self._keys = np.empty((b, 3, 4))
        self._unbind = np.linalg.inv(self.bind)

    @property
    def num_frames(self) -> int:
        return len(self._translations)

    def _local_keys(self, world: np.ndarray) -> np.ndarray:
        """(b, 3, 4) keys (translation column, rotation block) of each joint node for rigid maps
        world (b, 3, 4) of rest points; fills ``written``. Where every joint's parent node is a
        similarity at rest (no non-uniform scale above it: the usual case) the keys reproduce the
        world exactly, in one pass; otherwise parents' keys come first, level by level, so each
        translation still puts the pivot where the world puts it."""
        posed = self._posed
        posed[:, :3] = compose(world, self.bind[:, :3])  # the joints' posed world transforms
        W, keys = self._world4, self._keys
        if self.exact:
            W[...] = posed
        for level in self.levels:
            up = self.up_joint[level]
            Wp = self.above[level].copy()
            has = up >= 0
            Wp[has] = W[up[has]] @ Wp[has]
            local = np.linalg.solve(Wp, posed[level])
            keys[level, :, 3] = local[:, :3, 3]
            scale = self.node_scale[level]
            keys[level, :, :3] = polar_rotations(local[:, :3, :3] / scale[:, None, :])
            if not self.exact:
                node = np.tile(np.eye(4), (len(level), 1, 1))
                node[:, :3, :3] = keys[level, :, :3] * scale[:, None, :]
                node[:, :3, 3] = keys[level, :, 3]
                W[level] = Wp @ node
        if self.exact:
            self.written[...] = world
        else:
            self.written[...] = (W @ self._unbind)[:, :3]
        return keys

    def pose_keys(self, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One frame's keys without writing it: (b, 3) translations and (b, 4) rotations
        (x, y, z, w) of the joint nodes, parent-relative, for rigid maps world (b, 3, 4)
        (the live link sends exactly what the file would hold)."""
        local = self._local_keys(np.asarray(world, np.float64))
        return local[:, :, 3], matrix_to_quaternion(local[:, :, :3])

    def write(self, world: np.ndarray) -> None:
        """Append one frame. world: (b, 3, 4) rigid maps of rest points to posed points."""
        self._check_open()
        local = self._local_keys(np.asarray(world, np.float64))
        q = matrix_to_quaternion(local[:, :, :3])
        if self._previous_q is not None:  # stay on the hemisphere of the last key
            q *= np.where((q * self._previous_q).sum(1, keepdims=True) < 0, -1.0, 1.0)
        self._previous_q = q
        self._translations.append(local[:, :, 3].astype(np.float32))
        self._rotations.append(q.astype(np.float32))

    def timing(self) -> dict:
        """The take's rate and frame range as written in the scene's and the animation's extras:
        {"puppet_fps": frames per second, "puppet_frame_start": 1, "puppet_frame_end": N}, and
        its sound and start timecode (``sync``, puppet.export.sync).
        Blender's glTF importer (``import_scene_extras``, on by default) makes the scene's extras
        custom properties of the scene it imports into; it does not change the scene's rate or
        range itself, and places key time t on frame t × the scene's fps."""
        return {**self.sync, "puppet_fps": self.fps, "puppet_frame_start": 1,
                "puppet_frame_end": self.num_frames}

    def skin(self, world: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) linear blend skinning of the written skin for world (b, 3, 4): what a viewer shows
        (give it ``written``).

        Evaluated as one product ``L @ X`` with L (n, 4b) the file's weights times the rest
        vertices in homogeneous coordinates and X (4b, 3) the stacked transposed transforms.
        """
        if self._lbs is None:
            n = len(self.V)
            dense = np.zeros((n, self.b))
            for s in range(self.joints.shape[1]):
                np.add.at(dense, (np.arange(n), self.joints[:, s]), self.weights[:, s])
            Vh = np.hstack([self.V, np.ones((n, 1))])
            self._lbs = (dense[:, :, None] * Vh[:, None, :]).reshape(n, 4 * self.b)
            self._stacked = np.empty((self.b, 4, 3))
        P = np.asarray(world, np.float64)
        self._stacked[:, :3, :] = np.swapaxes(P[:, :, :3], 1, 2)
        self._stacked[:, 3, :] = P[:, :, 3]
        if out is None:
            out = np.empty((len(self.V), 3))
        return np.matmul(self._lbs, self._stacked.reshape(4 * self.b, 3), out=out)

    def close(self) -> None:
        """Write the file (at least one frame is needed). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if not self._translations:
            raise ExportError(self.path, "no frames to write")
        gltf = self._document()
        try:
            gltf.save_binary(str(self.path))
        except OSError as e:
            raise ExportError(self.path, f"cannot write glTF: {e.strerror}") from e

    def abort(self) -> None:
        """Drop the collected keys without writing."""
        self._closed = True
        self._translations.clear()
        self._rotations.clear()

    # ---- the document: nodes, meshes, materials ----
    def _nodes(self, gltf: pygltflib.GLTF2) -> None:
        """Every node of the scene, same order; mesh nodes get mesh k and skin 0."""
        for node in self.scene.nodes:
            kw = {}
            if node.joint >= 0 or node.matrix is None:
                t, r, s = _node_trs(node)
                kw = {"translation": [float(x) for x in t], "rotation": [float(x) for x in r]}
                if node.scale is not None or node.matrix is not None:
                    kw["scale"] = [float(x) for x in s]
            else:
                kw = {"matrix": list(node.matrix)}
            gltf.nodes.append(pygltflib.Node(
                name=node.name, children=list(node.children) or None,
                mesh=node.mesh if node.mesh >= 0 else None, skin=0 if node.mesh >= 0 else None, **kw))
        gltf.scenes.append(pygltflib.Scene(name=self.name, nodes=list(self.scene.roots)))
        gltf.scene = 0

    def _materials(self, gltf: pygltflib.GLTF2, blob: "_Blob") -> None:
        """The scene's materials, textures, samplers and images (embedded in the binary chunk);
        a texture whose image cannot be read is left out, and a warning names the file."""
        scene = self.scene
        images: dict[int, int] = {}
        for i, image in enumerate(scene.images):
            if image is None:
                continue
            data, warning = image.read()
            if warning:
                self.warnings.append(warning)
                continue
            images[i] = len(gltf.images)
            gltf.images.append(pygltflib.Image(name=image.name, mimeType=image.mime_type,
                                               bufferView=blob.view(data)))
        remap: dict[int, int] = {}
        for k, texture in enumerate(scene.textures):
            if texture.get("source") not in images:
                continue
            remap[k] = len(gltf.textures)
            sampler = texture.get("sampler")
            gltf.textures.append(pygltflib.Texture.from_dict(dict(
                texture, source=images[texture["source"]],
                sampler=sampler if isinstance(sampler, int) and sampler < len(scene.samplers) else None)))
        gltf.samplers.extend(pygltflib.Sampler.from_dict(s) for s in scene.samplers)
        materials = [_texture_refs(m, remap) for m in scene.materials]
        gltf.materials.extend(pygltflib.Material.from_dict(m) for m in materials)
        used = _extension_names(materials + [t.to_dict() for t in gltf.textures], set())
        if used:
            gltf.extensionsUsed = sorted(used)

    def _meshes(self, gltf: pygltflib.GLTF2, blob: "_Blob") -> None:
        """One mesh per skinned mesh node: the scene's primitives over the vertices in the file's
        order (POSITION in the mesh node's space, the scene's attributes, the skin)."""
        scene, b = self.scene, self.b
        to_mesh = np.linalg.inv(self.mesh_world)
        positions = (self.V @ to_mesh[:3, :3].T + to_mesh[:3, 3]).astype(np.float32)
        normals = vertex_normals(positions.astype(np.float64), self.F)
        joint_type, joint_dtype = (UINT8, np.uint8) if b <= 256 else (UINT16, np.uint16)
        for k, prims in enumerate(scene.primitives):
            written = []
            for prim in prims:
                rows = slice(prim.start, prim.start + prim.count)
                normal = scene.attributes["NORMAL"][rows] if "NORMAL" in prim.attributes else normals[rows]
                attributes = pygltflib.Attributes(
                    POSITION=blob.add(positions[rows], FLOAT, "VEC3", target=ARRAY_BUFFER, minmax=True),
                    NORMAL=blob.add(normal, FLOAT, "VEC3", target=ARRAY_BUFFER))
                for attribute in prim.attributes:
                    if attribute != "NORMAL":
                        values = scene.attributes[attribute][rows]
                        setattr(attributes, attribute, blob.add(
                            values, FLOAT, f"VEC{values.shape[1]}", target=ARRAY_BUFFER))
                for s in range(self.joints.shape[1] // 4):
                    cols = slice(4 * s, 4 * s + 4)
                    setattr(attributes, f"JOINTS_{s}", blob.add(
                        self.joints[rows, cols].astype(joint_dtype), joint_type, "VEC4", target=ARRAY_BUFFER))
                    setattr(attributes, f"WEIGHTS_{s}", blob.add(
                        self.weights[rows, cols], FLOAT, "VEC4", target=ARRAY_BUFFER))
                index_type, index_dtype = ((UINT16, np.uint16) if prim.count < 65535
                                           else (UINT32, np.uint32))
                indices = blob.add(prim.indices.astype(index_dtype), index_type, "SCALAR",
                                   target=ELEMENT_ARRAY_BUFFER)
                material = prim.material if prim.material is not None and \
                    prim.material < len(gltf.materials) else None
                written.append(pygltflib.Primitive(attributes=attributes, indices=indices, mode=4,
                                                   material=material))
            gltf.meshes.append(pygltflib.Mesh(name=scene.mesh_names[k] or self.name, primitives=written))
        ibm = np.einsum("bij,jk->bik", self._unbind, self.mesh_world)[:, :3]
        skeleton = scene.skeleton_node
        gltf.skins.append(pygltflib.Skin(name=f"{self.name} skeleton",
                                         joints=[int(n) for n in self.node_of_joint],
                                         inverseBindMatrices=blob.add(_column_major(ibm), FLOAT, "MAT4"),
                                         skeleton=skeleton))

    def _document(self) -> pygltflib.GLTF2:
        gltf = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0", generator="puppet"))
        blob = _Blob(gltf)
        self._nodes(gltf)
        self._materials(gltf, blob)
        self._meshes(gltf, blob)
        self._animation(gltf, blob)
        data = blob.bytes()
        gltf.buffers.append(pygltflib.Buffer(byteLength=len(data)))
        gltf.set_binary_blob(data)
        return gltf

    def _animation(self, gltf: pygltflib.GLTF2, blob: _Blob) -> None:
        """Animation 0: a translation and a rotation channel per joint (LINEAR), every frame a key
        or, with a key tolerance, the keys ``reduce_curve`` keeps (forced_frames among them; channels with the same kept
        frames share one key-time accessor); the timing in the scene's and animation's extras."""
        N = self.num_frames
        times = (np.arange(1, N + 1) / self.fps).astype(np.float32)
        translations = np.stack(self._translations, 1)  # (b, N, 3)
        rotations = np.stack(self._rotations, 1)        # (b, N, 4)
        time_accessors: dict[tuple[int, ...], int] = {}
        samplers, channels = [], []
        self.keys_kept = {}
        for j in range(self.b):
            kept = {}
            for path, values, kind, tol in (("translation", translations[j], "VEC3", self.keys_units),
                                            ("rotation", rotations[j], "VEC4", self.keys_deg)):
                keys = (np.arange(N) if tol is None else
                        reduce_curve(times, values.astype(np.float64), path, tol,
                                     forced=self.forced_frames[self.forced_frames < N]))
                kept[path] = len(keys)
                key_tuple = tuple(int(k) for k in keys)
                if key_tuple not in time_accessors:
                    time_accessors[key_tuple] = blob.add(times[keys], FLOAT, "SCALAR", minmax=True)
                out = blob.add(values[keys], FLOAT, kind)
                samplers.append(pygltflib.AnimationSampler(input=time_accessors[key_tuple], output=out,
                                                           interpolation="LINEAR"))
                channels.append(pygltflib.AnimationChannel(
                    sampler=len(samplers) - 1,
                    target=pygltflib.AnimationChannelTarget(node=int(self.node_of_joint[j]), path=path)))
            self.keys_kept[self.names[j]] = kept
        timing = self.timing()
        gltf.animations.append(pygltflib.Animation(
            name=self.name, samplers=samplers, channels=channels,
            extras={**timing, "note": "frame k is at k/fps seconds; frame 1 is the take's first "
                                      "reading"}))
        gltf.scenes[gltf.scene].extras = {**(gltf.scenes[gltf.scene].extras or {}), **timing}
