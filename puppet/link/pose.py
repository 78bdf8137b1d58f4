"""What the link sends of a solve: each joint's glTF keys and, on request, the FAST vertices.

The keys are ``puppet export --gltf``'s own (``GltfWriter.pose_keys`` of ``JointTransforms``'
rigid maps): a frame applied in Blender equals that frame of the exported file. The vertices are
``V' = M T`` in the character file's vertex order (``SourceOrder``), as the exports write them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from puppet.export.gltf import GltfWriter
from puppet.export.joint_transforms import JointTransforms
from puppet.export.source_order import SourceOrder


class LinkPose:
    """Keys and vertices of one rig's solves, into preallocated arrays.

    rig: the Rig; lbs: a callable giving the (n, 4m) LBS matrix (asked for on the first mesh
    frame only). Fields: parents (b,) each joint's nearest joint above in the file's nodes (-1:
    none), above (b, 4, 4) its parent node's rest transform in that joint's space (or in the
    armature node's: ``SourceScene.object_world``), armature (4, 4) that node's rest world (see
    ``puppet.link.wire``). After ``update(T, mesh)``: translations (b, 3) float64, rotations
    (b, 4) float64 (x, y, z, w), vertices (n_out, 3) float32 (filled when ``mesh``).
    """

    def __init__(self, rig, lbs):
        sk = rig.skeleton
        self.order = SourceOrder(rig)
        self.names = [str(n) for n in sk.names]
        self.keys = GltfWriter(Path(f"{rig.name}.link"), names=sk.names, parents=sk.parents,
                               heads=sk.heads, frames=sk.frames, V=self.order.take(rig.V),
                               F=self.order.F, W=self.order.take(rig.W), fps=30.0, name=rig.name,
                               source=rig.source)
        self.parents = [int(p) for p in self.keys.up_joint]
        self.armature = np.array(self.keys.scene.object_world, np.float64)
        self.above = np.array(self.keys.above)
        roots = self.keys.up_joint < 0
        self.above[roots] = np.linalg.solve(self.armature, self.above[roots])
        self.joints = JointTransforms(sk.heads)
        b = len(self.names)
        identity = np.zeros((b, 3, 4))
        identity[:, :, :3] = np.eye(3)
        rest_t, rest_q = self.keys.pose_keys(identity)
        self.rest_translations, self.rest_rotations = np.array(rest_t), np.array(rest_q)
        self.translations = np.zeros((b, 3))
        self.rotations = np.zeros((b, 4))
        self.n_vertices = self.order.n_out
        self.vertices = np.zeros((self.n_vertices, 3), np.float32)
        self._lbs = lbs
        self._M = None  # (n, 4m) float32: the vertices are float32 on the wire anyway, and the
        self._T = None  # product is 4.4x quicker than in float64 (0.8 ms for the critter)
        self._deformed = None

    def update(self, T: np.ndarray, mesh: bool) -> None:
        """Fill the keys (and the vertices when ``mesh``) from a solve's T (4m, 3)."""
        self.joints.update(T)
        t, q = self.keys.pose_keys(self.joints.world)
        self.translations[...] = t
        self.rotations[...] = q
        if mesh:
            if self._M is None:
                self._M = np.ascontiguousarray(self._lbs(), dtype=np.float32)
                self._T = np.empty(T.shape, np.float32)
                self._deformed = np.empty((self._M.shape[0], 3), np.float32)
            self._T[...] = T
            np.matmul(self._M, self._T, out=self._deformed)
            self.order.take(self._deformed, out=self.vertices)
