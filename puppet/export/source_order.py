"""The character file's own vertex order, for outputs that must fit the file (PC2, glTF, USD).

A loader may weld copies of a vertex that the file split (UV seams, split normals); the rig then
records ``source_index`` (n_source,): for each vertex of the file, in the file's order, its index
in the welded ``rig.V``. Outputs list vertices in the file's order: ``deformed[source_index]``.
Triangles are the file's own (every primitive's indices, in order) when the rig came from a
glTF file (``Rig.source``); otherwise the rig's triangles, which index welded vertices, use the
first file vertex of each welded one.
"""

from __future__ import annotations

import numpy as np

from puppet.export.errors import ExportError


class SourceOrder:
    """Maps welded rig vertices to the character file's vertex order.

    index: (n_out,) int64 rig vertex of each output vertex (identity when the rig has no map).
    F:     (f, 3) int64 triangles as indices into the output vertices: the file's own, or the
           rig's mapped onto the first file copy of each vertex.
    n_out: number of output vertices (the file's vertex count).
    """

    def __init__(self, rig):
        n = len(rig.V)
        F = np.asarray(rig.F, np.int64)
        if rig.source_index is None:
            self.index = np.arange(n, dtype=np.int64)
            self.identity = True
            self.F = F
        else:
            index = np.asarray(rig.source_index, np.int64).reshape(-1)
            if index.size and (index.min() < 0 or index.max() >= n):
                raise ExportError(rig.path or rig.name, f"source_index holds vertex "
                                  f"{int(index.max() if index.max() >= n else index.min())}, "
                                  f"the rig has {n} vertices")
            first = np.full(n, -1, np.int64)
            first[index[::-1]] = np.arange(len(index) - 1, -1, -1)  # first file copy of each
            missing = np.flatnonzero(first[np.unique(F)] < 0) if len(F) else np.zeros(0, int)
            if missing.size:
                v = int(np.unique(F)[missing[0]])
                raise ExportError(rig.path or rig.name, f"rig vertex {v} has no vertex in the "
                                                        "character file (source_index)")
            self.index = index
            self.identity = False
            self.F = first[F]
        self.n_out = len(self.index)
        source = rig.source
        if source is not None:
            counts = sum(p.count for prims in source.primitives for p in prims)
            if counts != self.n_out:
                raise ExportError(rig.path or rig.name, f"the character file's primitives hold "
                                  f"{counts} vertices, the rig maps {self.n_out}")
            self.F = source.triangles

    def take(self, values: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Rows of values (n, ...) in the file's order: values[index]."""
        if self.identity:
            if out is None:
                return values
            out[...] = values
            return out
        return np.take(values, self.index, axis=0, out=out)
