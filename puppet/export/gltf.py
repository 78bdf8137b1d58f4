"""glTF 2.0 binary (.glb): the character with its skin and one animation of every joint.

Layout of the file written:
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
                                            rest_globals, rigid_inverse)
from puppet.export.writer import ExportWriter

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

    def add(self, array: np.ndarray, component: int, kind: str, *, target=None,
            minmax: bool = False) -> int:
        data = np.ascontiguousarray(array)
        raw = data.tobytes()
        self.gltf.bufferViews.append(pygltflib.BufferView(
            buffer=0, byteOffset=self.size, byteLength=len(raw), target=target))
        self.parts.append(raw)
        self.size += len(raw)
        pad = (-self.size) % 4
        if pad:
            self.parts.append(b"\0" * pad)
            self.size += pad
        rows = data.reshape(len(data), -1)
        accessor = pygltflib.Accessor(bufferView=len(self.gltf.bufferViews) - 1,
                                      componentType=component, count=len(data), type=kind)
        if minmax:
            accessor.min = [float(x) for x in rows.min(0)]
            accessor.max = [float(x) for x in rows.max(0)]
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


class GltfWriter(ExportWriter):
    """Collects one animation key per frame; ``close()`` writes the .glb in one piece.

    path:       output .glb file (written only by close()).
    names:      b joint names; parents (b,) int (-1 for roots, parents before children).
    heads:      (b, 3) rest pivots; frames (b, 3, 3) rest frames (columns = local axes).
    V:          (n, 3) rest vertices in the file's order; F (f, 3) triangles into V.
    W:          (n, b) bone weights in the same vertex order.
    fps:        frames per second of the keys.
    influences: weights kept per vertex (a multiple of 4: one JOINTS_n/WEIGHTS_n set per 4).
    name:       name of the mesh, its node and the animation.
    keys_deg:   None: a key on every frame; else rotation keys reduced to this tolerance, degrees
                (``puppet.export.key_reduction``). keys_units: the same for translations, model
                units (None: every frame).
    Fields: joints (n, influences) int64 and weights (n, influences) float32: the skin as written;
    keys_kept {joint name: {"translation": keys, "rotation": keys}} once closed.
    """

    close_on_error = False  # the .glb is written in one piece: an error inside `with` writes none

    def __init__(self, path, *, names, parents, heads, frames, V, F, W, fps: float,
                 influences: int = 4, name: str = "character", keys_deg: float | None = None,
                 keys_units: float | None = None):
        self.path = Path(path)
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
        self.keys_kept: dict[str, dict[str, int]] = {}
        self.joints, self.weights = top_weights(W, influences)
        self._translations: list[np.ndarray] = []
        self._rotations: list[np.ndarray] = []
        self._previous_q = None
        self._lbs = None
        self._closed = False

    @property
    def num_frames(self) -> int:
        return len(self._translations)

    def write(self, world: np.ndarray) -> None:
        """Append one frame. world: (b, 3, 4) rigid maps of rest points to posed points."""
        self._check_open()
        posed = compose(np.asarray(world, np.float64), self.rest)
        local = local_transforms(posed, self.parents)
        q = matrix_to_quaternion(local[:, :, :3])
        if self._previous_q is not None:  # stay on the hemisphere of the last key
            q *= np.where((q * self._previous_q).sum(1, keepdims=True) < 0, -1.0, 1.0)
        self._previous_q = q
        self._translations.append(local[:, :, 3].astype(np.float32))
        self._rotations.append(q.astype(np.float32))

    def timing(self) -> dict:
        """The take's rate and frame range as written in the scene's and the animation's extras:
        {"puppet_fps": frames per second, "puppet_frame_start": 1, "puppet_frame_end": N}.
        Blender's glTF importer (``import_scene_extras``, on by default) makes the scene's extras
        custom properties of the scene it imports into; it does not change the scene's rate or
        range itself, and places key time t on frame t × the scene's fps."""
        return {"puppet_fps": self.fps, "puppet_frame_start": 1,
                "puppet_frame_end": self.num_frames}

    def skin(self, world: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) linear blend skinning of the written skin for world (b, 3, 4): what a viewer shows.

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


    # ---- the document ----
    def _document(self) -> pygltflib.GLTF2:
        gltf = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0", generator="puppet"))
        blob = _Blob(gltf)
        b = self.b
        local_rest = local_transforms(self.rest, self.parents)
        q_rest = matrix_to_quaternion(local_rest[:, :, :3])
        for j in range(b):
            children = [int(c) for c in np.flatnonzero(self.parents == j)]
            gltf.nodes.append(pygltflib.Node(
                name=self.names[j], children=children or None,
                translation=[float(x) for x in local_rest[j, :, 3]],
                rotation=[float(x) for x in q_rest[j]]))
        # Mesh.
        attributes = pygltflib.Attributes(
            POSITION=blob.add(self.V.astype(np.float32), FLOAT, "VEC3", target=ARRAY_BUFFER,
                              minmax=True),
            NORMAL=blob.add(vertex_normals(self.V, self.F), FLOAT, "VEC3", target=ARRAY_BUFFER))
        joint_type, joint_dtype = (UINT8, np.uint8) if b <= 256 else (UINT16, np.uint16)
        for s in range(self.joints.shape[1] // 4):
            cols = slice(4 * s, 4 * s + 4)
            setattr(attributes, f"JOINTS_{s}", blob.add(self.joints[:, cols].astype(joint_dtype),
                                                       joint_type, "VEC4", target=ARRAY_BUFFER))
            setattr(attributes, f"WEIGHTS_{s}", blob.add(self.weights[:, cols], FLOAT, "VEC4",
                                                        target=ARRAY_BUFFER))
        index_type, index_dtype = (UINT16, np.uint16) if len(self.V) < 65535 else (UINT32, np.uint32)
        indices = blob.add(self.F.reshape(-1).astype(index_dtype), index_type, "SCALAR",
                           target=ELEMENT_ARRAY_BUFFER)
        gltf.meshes.append(pygltflib.Mesh(name=self.name, primitives=[
            pygltflib.Primitive(attributes=attributes, indices=indices, mode=4)]))
        ibm = blob.add(_column_major(rigid_inverse(self.rest)), FLOAT, "MAT4")
        roots = [int(r) for r in np.flatnonzero(self.parents < 0)]
        gltf.skins.append(pygltflib.Skin(name=f"{self.name} skeleton", joints=list(range(b)),
                                         inverseBindMatrices=ibm,
                                         skeleton=roots[0] if len(roots) == 1 else None))
        gltf.nodes.append(pygltflib.Node(name=self.name, mesh=0, skin=0))
        gltf.scenes.append(pygltflib.Scene(name=self.name, nodes=roots + [b]))
        gltf.scene = 0
        self._animation(gltf, blob)
        data = blob.bytes()
        gltf.buffers.append(pygltflib.Buffer(byteLength=len(data)))
        gltf.set_binary_blob(data)
        return gltf

    def _animation(self, gltf: pygltflib.GLTF2, blob: _Blob) -> None:
        """Animation 0: a translation and a rotation channel per joint (LINEAR), every frame a key
        or, with a key tolerance, the keys ``reduce_curve`` keeps (channels with the same kept
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
                        reduce_curve(times, values.astype(np.float64), path, tol))
                kept[path] = len(keys)
                key_tuple = tuple(int(k) for k in keys)
                if key_tuple not in time_accessors:
                    time_accessors[key_tuple] = blob.add(times[keys], FLOAT, "SCALAR", minmax=True)
                out = blob.add(values[keys], FLOAT, kind)
                samplers.append(pygltflib.AnimationSampler(input=time_accessors[key_tuple], output=out,
                                                           interpolation="LINEAR"))
                channels.append(pygltflib.AnimationChannel(
                    sampler=len(samplers) - 1,
                    target=pygltflib.AnimationChannelTarget(node=j, path=path)))
            self.keys_kept[self.names[j]] = kept
        timing = self.timing()
        gltf.animations.append(pygltflib.Animation(
            name=self.name, samplers=samplers, channels=channels,
            extras={**timing, "note": "frame k is at k/fps seconds; frame 1 is the take's first "
                                      "reading"}))
        gltf.scenes[gltf.scene].extras = {**(gltf.scenes[gltf.scene].extras or {}), **timing}
