"""BVH motion capture files of a skeleton's joint rotations: a streaming writer.

A BVH file has a HIERARCHY (ROOT, JOINT and End Site blocks with OFFSET and CHANNELS) and a
MOTION section (Frames, Frame Time, then one line of channel values per frame). A joint's
world transform is parent_world @ translate(OFFSET) @ R, with R = R_axis1 @ R_axis2 @ R_axis3
for the channel order axis1 axis2 axis3 (degrees). The root also has X/Y/Zposition channels:
its position in the world, which replaces its OFFSET while the motion plays.

Joint names are the rig's, under the ``"bvh"`` rule of ``puppet.export.names`` (whitespace and
control characters -> ``_``, accents dropped; dots, ``.L``/``.R`` and other punctuation kept, as
Blender's importer keeps them), so the BVH drives a mesh through its vertex groups unrenamed.
A leaf joint's End Site takes its length from the mesh (``mesh_end_sites``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

import numpy as np

from puppet.export.errors import ExportError
from puppet.export.euler import ORDERS, matrix_to_euler
from puppet.export.names import safe_name
from puppet.export.writer import CountPatchedWriter

_FRAMES_FIELD = 12  # "Frames:" is padded to this width so close() can patch the count in place


def mesh_end_sites(heads, tails, frames, parents, V, W) -> np.ndarray:
    """(b, 3) End Site offsets of the leaf joints, measured on the mesh (other rows: tails - heads).

    heads, tails: (b, 3) rest pivots and tips; frames: (b, 3, 3) rest frames (column 1: the
    bone's local +Y); parents: (b,) int; V: (n, 3) rest vertices; W: (n, >= b) weights, column j
    = bone j. A leaf's End Site points along its bone (tail - head, or the frame's +Y for a bone
    of no length) and reaches the farthest vertex along that direction among the vertices whose
    largest weight is that bone: its length is max((v - head) · direction). A leaf that no vertex
    follows most (or whose vertices all lie behind its pivot) keeps the rig's tail - head.
    """
    heads = np.asarray(heads, np.float64)
    out = np.asarray(tails, np.float64) - heads
    parents = np.asarray(parents)
    V = np.asarray(V, np.float64)
    W = np.asarray(W, np.float64)
    dominant = np.argmax(W, axis=1) if len(V) else np.empty(0, np.int64)
    leaves = sorted(set(range(len(heads))) - set(parents[parents >= 0].tolist()))
    for j in leaves:
        length = float(np.linalg.norm(out[j]))
        direction = out[j] / length if length > 1e-12 else np.asarray(frames[j], np.float64)[:, 1]
        mine = V[dominant == j]
        reach = float(((mine - heads[j]) @ direction).max()) if len(mine) else 0.0
        if reach > 1e-12:
            out[j] = reach * direction
    return out


class BvhWriter(CountPatchedWriter):
    """Writes a skeleton's hierarchy, then one frame of joint rotations at a time.

    path:      output .bvh file.
    names:     b joint names, unique, each unchanged by ``safe_name(name, "bvh")``.
    parents:   (b,) int, parent joint index, -1 for the one root.
    offsets:   (b, 3) float, each joint's rest position relative to its parent's joint (the
               root's: its rest position in the world), in the skeleton's length unit.
    frame_time: seconds per frame (1 / fps).
    order:     Euler order of the rotation channels, one of XYZ XZY YXZ YZX ZXY ZYX.
    end_sites: (b, 3) float or None: End Site offset of each leaf joint (rows of other joints
               are unused); None: a leaf's End Site continues its own offset direction.
    precision: decimals written for every value.
    positions: "root": only the root has X/Y/Zposition channels (the classic layout); "all": every
               joint has them, holding its translation from its parent joint in the parent's
               frame (it replaces the OFFSET while the motion plays, as Blender's importer
               reads it), so joints whose distance to their parent changes stay exact.
    Joints are written depth first from the root, children in index order; motion channels
    follow that order.
    """

    def __init__(
        self,
        path,
        *,
        names,
        parents,
        offsets,
        frame_time: float,
        order: str = "ZXY",
        end_sites=None,
        precision: int = 6,
        positions: str = "root",
        sync: dict | None = None,
    ):
        self.path = Path(path)
        self.sync = dict(sync or {})  # puppet.export.sync: one comment line after HIERARCHY
        if positions not in ("root", "all"):
            raise ExportError(self.path, f"positions must be 'root' or 'all', got {positions!r}")
        self.positions = positions
        self.names = [str(n) for n in names]
        self.parents = np.asarray(parents, dtype=np.int64).ravel()
        self.offsets = np.asarray(offsets, dtype=np.float64)
        self.order = order
        self.frame_time = float(frame_time)
        self.b = len(self.names)
        self.num_frames = 0
        self._fmt = f"{{:.{int(precision)}f}}"
        self._check_skeleton(end_sites)
        self.dfs = self._depth_first()
        self._previous = None
        self._closed = False
        try:
            self._file = open(self.path, "w", encoding="ascii", newline="\n")
        except OSError as e:
            raise ExportError(self.path, f"cannot create BVH file: {e.strerror}") from e
        self._file.write(self._hierarchy_text(end_sites))
        self._file.write("MOTION\n")
        self._frames_at = self._file.tell()
        self._file.write(f"Frames: {'0'.ljust(_FRAMES_FIELD)}\n")
        self._file.write(f"Frame Time: {self.frame_time:.9f}\n")

    # ---- skeleton ----
    def _check_skeleton(self, end_sites) -> None:
        p = self.path
        if self.b == 0:
            raise ExportError(p, "skeleton has no joints")
        for i, n in enumerate(self.names):
            if safe_name(n, "bvh") != n:
                raise ExportError(p, f"joint {i} name {n!r}: BVH names must be non-empty ASCII "
                                     "without whitespace or control characters")
        dup = sorted({n for n in self.names if self.names.count(n) > 1})
        if dup:
            raise ExportError(p, f"duplicate joint names {dup}")
        if self.parents.shape != (self.b,):
            raise ExportError(p, f"parents has {self.parents.size} entries, names {self.b}")
        if self.offsets.shape != (self.b, 3) or not np.isfinite(self.offsets).all():
            raise ExportError(p, f"offsets must be finite ({self.b}, 3), got {self.offsets.shape}")
        roots = np.flatnonzero(self.parents == -1).tolist()
        if len(roots) != 1:
            raise ExportError(p, f"a BVH skeleton has one root (parent -1), got joints {roots}")
        for i, q in enumerate(self.parents.tolist()):
            if q != -1 and not 0 <= q < self.b or q == i:
                raise ExportError(p, f"joint {self.names[i]!r} has bad parent {q}")
        if self.order not in ORDERS:
            raise ExportError(p, f"Euler order must be one of {ORDERS}, got {self.order!r}")
        if not (np.isfinite(self.frame_time) and self.frame_time > 0):
            raise ExportError(p, f"frame_time must be > 0 seconds, got {self.frame_time}")
        if end_sites is not None and np.shape(end_sites) != (self.b, 3):
            raise ExportError(p, f"end_sites must be ({self.b}, 3), got {np.shape(end_sites)}")

    def _children(self) -> list[list[int]]:
        children: list[list[int]] = [[] for _ in range(self.b)]
        for i, q in enumerate(self.parents.tolist()):
            if q >= 0:
                children[q].append(i)
        return children

    def _depth_first(self) -> list[int]:
        children = self._children()
        root = int(np.flatnonzero(self.parents == -1)[0])
        out, stack = [], [root]
        while stack:
            j = stack.pop()
            out.append(j)
            stack.extend(reversed(children[j]))
        if len(out) != self.b:
            cut = sorted(set(range(self.b)) - set(out))
            raise ExportError(self.path, f"joints {[self.names[j] for j in cut]} are not "
                                         "connected to the root (a cycle in parents)")
        return out

    def _hierarchy_text(self, end_sites) -> str:
        children = self._children()
        f = self._fmt
        rot = " ".join(f"{a}rotation" for a in self.order)
        lines = ["HIERARCHY"]
        if self.sync:  # a comment (importers skip a line they do not know), ASCII as the file
            lines.append("# puppet " + json.dumps(self.sync, ensure_ascii=True))

        def vec(v) -> str:
            return " ".join(f.format(float(x)) for x in v)

        def emit(j: int, depth: int) -> None:
            pad = "\t" * depth
            if self.parents[j] == -1:
                lines.append(f"{pad}ROOT {self.names[j]}")
                channels = f"CHANNELS 6 Xposition Yposition Zposition {rot}"
            else:
                lines.append(f"{pad}JOINT {self.names[j]}")
                channels = (f"CHANNELS 6 Xposition Yposition Zposition {rot}"
                            if self.positions == "all" else f"CHANNELS 3 {rot}")
            lines.append(pad + "{")
            lines.append(f"{pad}\tOFFSET {vec(self.offsets[j])}")
            lines.append(f"{pad}\t{channels}")
            for c in children[j]:
                emit(c, depth + 1)
            if not children[j]:
                if end_sites is not None:
                    tip = np.asarray(end_sites[j], dtype=np.float64)
                else:
                    tip = self.offsets[j] if self.parents[j] != -1 else np.array([0.0, 1.0, 0.0])
                lines.append(f"{pad}\tEnd Site")
                lines.append(f"{pad}\t{{")
                lines.append(f"{pad}\t\tOFFSET {vec(tip)}")
                lines.append(f"{pad}\t}}")
            lines.append(pad + "}")

        emit(self.dfs[0], 0)
        return "\n".join(lines) + "\n"

    # ---- motion ----
    def write(self, rotations: np.ndarray, root_position=None, positions=None) -> None:
        """Append one frame.

        rotations:     (b, 3, 3) rotation matrices, each joint's rotation relative to its
                       parent (identity = rest pose), or (b, 3) Euler angles in degrees in the
                       writer's order.
        root_position: (3,) root position in the world; None: the root's rest offset.
        positions:     with positions="all": (b, 3) each joint's translation from its parent
                       joint in the parent's frame (the root's: its world position; it then
                       replaces root_position); None: the rest offsets.
        """
        self._check_open()
        n = self.num_frames
        rotations = np.asarray(rotations, dtype=np.float64)
        if rotations.shape == (self.b, 3, 3):
            dev = np.abs(rotations @ np.swapaxes(rotations, -1, -2) - np.eye(3)).max(axis=(1, 2))
            det = np.linalg.det(rotations)
            bad = np.flatnonzero(~(dev < 1e-4) | ~(det > 0))
            if bad.size:
                j = int(bad[0])
                raise ExportError(self.path, f"frame {n}, joint {self.names[j]!r}: not a rotation "
                                             f"matrix (|R R^T - I| = {dev[j]:.3g}, det {det[j]:.3g})")
            angles = matrix_to_euler(rotations, self.order)
            if self._previous is not None:  # continuous curves: the nearest turn to last frame
                angles += 2 * np.pi * np.round((self._previous - angles) / (2 * np.pi))
            self._previous = angles
            degrees = np.degrees(angles)
        elif rotations.shape == (self.b, 3):
            if not np.isfinite(rotations).all():
                raise ExportError(self.path, f"frame {n}: Euler angles are not finite")
            degrees = rotations
        else:
            raise ExportError(self.path, f"frame {n}: rotations have shape {rotations.shape}, "
                                         f"expected ({self.b}, 3, 3) or ({self.b}, 3)")
        root = self.dfs[0]
        if positions is not None:
            if self.positions != "all":
                raise ExportError(self.path, "per-joint positions need positions='all'")
            positions = np.asarray(positions, dtype=np.float64)
            if positions.shape != (self.b, 3) or not np.isfinite(positions).all():
                raise ExportError(self.path, f"frame {n}: positions must be finite ({self.b}, 3)")
            pos = positions[root]
        else:
            pos = self.offsets[root] if root_position is None else np.asarray(root_position, float)
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise ExportError(self.path, f"frame {n}: root_position must be finite (3,)")
        f = self._fmt
        values = [f.format(float(x)) for x in pos]
        for k, j in enumerate(self.dfs):
            if k and self.positions == "all":
                moved = self.offsets[j] if positions is None else positions[j]
                values.extend(f.format(float(x)) for x in moved)
            values.extend(f.format(float(x)) for x in degrees[j])
        self._file.write(" ".join(values) + "\n")
        self.num_frames += 1

    def _count_field(self) -> tuple[int, str]:
        """The "Frames:" line's place and its text with the frame count (patched by close())."""
        return self._frames_at, f"Frames: {str(self.num_frames).ljust(_FRAMES_FIELD)}"


def write_bvh(
    path,
    *,
    names,
    parents,
    offsets,
    frames: Iterable[np.ndarray],
    frame_time: float,
    order: str = "ZXY",
    root_positions=None,
    end_sites=None,
    precision: int = 6,
) -> int:
    """Write a BVH file in one call; returns the number of frames written.

    frames: (N, b, 3, 3) rotation matrices or (N, b, 3) Euler degrees (or an iterable of the
    per-frame arrays); root_positions: (N, 3) or None. Other arguments as in BvhWriter.
    """
    with BvhWriter(path, names=names, parents=parents, offsets=offsets, frame_time=frame_time,
                   order=order, end_sites=end_sites, precision=precision) as w:
        for n, rotations in enumerate(frames):
            w.write(rotations, None if root_positions is None else root_positions[n])
    return w.num_frames
