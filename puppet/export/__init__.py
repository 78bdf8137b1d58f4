"""Exports of a take for other tools, every one resampled to a frame rate (frame 1 = the first
reading) and written atomically:

- glTF 2.0 (.glb): the character with its skin and one animation of every joint (solved ones too);
- USD: the exact deformed mesh as time-sampled points, and the skeleton as UsdSkel;
- PC2 point cache of the deformed mesh in the character file's own vertex order;
- BVH with every joint (BVH-safe names).

``export_take`` runs the whole export of one take; the writers stream one frame at a time.
USD needs usd-core, imported only when a USD file is written.
"""

from puppet.export.bvh import BvhWriter, write_bvh
from puppet.export.errors import ExportError
from puppet.export.euler import euler_to_matrix, matrix_to_euler
from puppet.export.gltf import GltfWriter
from puppet.export.joint_transforms import JointTransforms, polar_rotations
from puppet.export.names import safe_names
from puppet.export.pc2 import Pc2Writer, write_pc2
from puppet.export.resample import Resampler, frame_offsets_ns
from puppet.export.run import FIRST_FRAME, FORMATS, ExportReport, Outputs, export_take
from puppet.export.source_order import SourceOrder

__all__ = [
    "BvhWriter",
    "ExportError",
    "ExportReport",
    "FIRST_FRAME",
    "FORMATS",
    "GltfWriter",
    "JointTransforms",
    "Outputs",
    "Pc2Writer",
    "Resampler",
    "SourceOrder",
    "euler_to_matrix",
    "export_take",
    "frame_offsets_ns",
    "matrix_to_euler",
    "polar_rotations",
    "safe_names",
    "write_bvh",
    "write_pc2",
]
