"""Exports of a take for DCC tools: the deformed mesh as a PC2 point cache, the sensed
skeleton's joint rotations as BVH. Both writers stream, one frame at a time."""

from puppet.export.bvh import BvhWriter, write_bvh
from puppet.export.errors import ExportError
from puppet.export.euler import euler_to_matrix, matrix_to_euler
from puppet.export.pc2 import Pc2Writer, write_pc2

__all__ = [
    "BvhWriter",
    "ExportError",
    "Pc2Writer",
    "euler_to_matrix",
    "matrix_to_euler",
    "write_bvh",
    "write_pc2",
]
