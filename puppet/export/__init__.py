"""Exports of a take for other tools, every one at a frame rate by the one take-to-frames rule
(``puppet.take.Playback``; frame 1 = the first reading) and written atomically:

- glTF 2.0 (.glb): the character with its skin and one animation of every joint (solved ones too),
  a key on every frame or, with ``keys``, per channel the keys that stay within a tolerance
  (``puppet.export.key_reduction``); for a glTF character, the file's own vertices, attributes,
  materials, images and nodes;
- USD: the exact deformed mesh as time-sampled points, and the skeleton as UsdSkel;
- PC2 point cache of the deformed mesh in the character file's own vertex order, in the mesh
  object's local space (``space="object"``, where Blender's glTF importer puts the mesh) or the
  model frame (``space="model"``);
- BVH with every joint, named as in the rig (whitespace -> ``_``: ``puppet.export.names``),
  End Sites measured on the mesh.

``export_take`` runs the whole export of one take; ``ExportWriters`` is its per-frame sink (also fed
beside a video by ``puppet.replay.play_take``); the writers stream one frame at a time.
USD needs usd-core, imported only when a USD file is written.
"""

from puppet.export.bvh import BvhWriter, mesh_end_sites, write_bvh
from puppet.export.errors import ExportError
from puppet.export.euler import euler_to_matrix, matrix_to_euler
from puppet.export.gltf import GltfWriter
from puppet.export.joint_transforms import JointTransforms, polar_rotations
from puppet.export.key_reduction import curve_error, reduce_curve
from puppet.export.names import safe_names
from puppet.export.pc2 import Pc2Writer, write_pc2
from puppet.export.run import (FIRST_FRAME, FORMATS, ExportReport, ExportWriters, Outputs,
                               check_fps, export_take)
from puppet.export.source_order import SourceOrder

__all__ = [
    "BvhWriter",
    "ExportError",
    "ExportReport",
    "ExportWriters",
    "FIRST_FRAME",
    "FORMATS",
    "GltfWriter",
    "JointTransforms",
    "Outputs",
    "Pc2Writer",
    "SourceOrder",
    "euler_to_matrix",
    "export_take",
    "check_fps",
    "curve_error",
    "matrix_to_euler",
    "mesh_end_sites",
    "polar_rotations",
    "reduce_curve",
    "safe_names",
    "write_bvh",
    "write_pc2",
]
