"""libigl skeleton (TGF) and matrix (DMAT) files.

TGF: one line per joint ``index x y z`` (1-based index), a line ``#``, then one line per edge
``a b [is_bone is_pseudo is_cage]`` (1-based joint indices). An edge is a bone when it has no
flags or ``is_bone`` is 1. Joints no bone touches are point handles. Bones are named
``bone<k>`` (k = 1-based position among the file's bones), point handles ``point<i>``
(i = the joint's 1-based index). libigl orders weight columns ``[point handles; bones]``.

DMAT: ASCII ``cols rows`` then the entries column by column; or binary: ``0 0``, then
``cols rows``, then little-endian float64 entries column by column.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from puppet.rig.errors import RigError
from puppet.rig.skeleton import Skeleton, frame_from_direction


def read_tgf(path) -> tuple[Skeleton, np.ndarray]:
    """Skeleton of a TGF file and, for each bone (skeleton order), its libigl weight column.

    Returns (skeleton, columns (bones,) int64): ``W_skeleton = W_libigl[:, columns]``.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise RigError("skeleton file not found", path=path) from None
    except (OSError, UnicodeDecodeError) as err:
        raise RigError(f"cannot read: {err}", path=path) from err
    joints: dict[int, np.ndarray] = {}
    edges: list[tuple[int, int, int]] = []  # (a, b, line), 0-based joints
    in_edges = False
    for number, line in enumerate(lines, 1):
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "#":
            in_edges = True
            continue
        try:
            if not in_edges:
                if len(parts) < 4:
                    raise ValueError
                index = int(parts[0])
                if index in joints or index < 1:
                    raise RigError(f"joint index {index} repeated or below 1", path=path, line=number,
                                   field="joint")
                joints[index] = np.array([float(x) for x in parts[1:4]])
            else:
                a, b = int(parts[0]), int(parts[1])
                flags = [int(float(x)) for x in parts[2:5]]
                if not flags or flags[0] == 1:
                    edges.append((a, b, number))
        except (ValueError, IndexError):
            raise RigError(f"cannot parse {line.strip()!r}", path=path, line=number,
                           field="edge" if in_edges else "joint") from None
    if not joints:
        raise RigError("no joints", path=path, field="joint")
    if sorted(joints) != list(range(1, len(joints) + 1)):
        raise RigError(f"joint indices must be 1..{len(joints)} (1-based)", path=path, field="joint")
    for a, b, number in edges:
        for end in (a, b):
            if end not in joints:
                raise RigError(f"edge references joint {end}, file has joints 1..{len(joints)} (1-based)",
                               path=path, line=number, field="edge")
        if a == b:
            raise RigError(f"edge {a} {b} joins a joint to itself", path=path, line=number, field="edge")
    in_bone = {a for a, b, _ in edges} | {b for a, b, _ in edges}
    points = [i for i in sorted(joints) if i not in in_bone]
    # libigl column of each handle: point handles first, then bones in file order.
    handles = [(f"point{i}", -1, i, i, col) for col, i in enumerate(points)]
    handles += [(f"bone{k + 1}", None, a, b, len(points) + k) for k, (a, b, _) in enumerate(edges)]
    # Parent of a bone: the bone whose tail is its head; order parents before children.
    tail_owner = {}
    for name, _, a, b, _ in handles[len(points):]:
        tail_owner.setdefault(b, name)
    by_name = {h[0]: h for h in handles}
    order: list[str] = []
    placed: set[str] = set()

    def place(name, stack=()):
        if name in placed:
            return
        if name in stack:
            raise RigError(f"bones form a cycle through {name}", path=path, field="edge")
        _, _, a, _, _ = by_name[name]
        parent = tail_owner.get(a) if not name.startswith("point") else None
        if parent is not None and parent != name:
            place(parent, stack + (name,))
        placed.add(name)
        order.append(name)

    for h in handles:
        place(h[0])
    index = {name: i for i, name in enumerate(order)}
    parents, heads, tails, columns = [], [], [], []
    for name in order:
        _, _, a, b, col = by_name[name]
        parent = tail_owner.get(a) if not name.startswith("point") else None
        parents.append(-1 if parent is None or parent == name else index[parent])
        heads.append(joints[a])
        tails.append(joints[b])
        columns.append(col)
    heads, tails = np.array(heads), np.array(tails)
    frames = np.array([frame_from_direction(t - h) for h, t in zip(heads, tails)])
    return Skeleton(tuple(order), np.array(parents), heads, tails, frames), np.array(columns, np.int64)


def read_dmat(path) -> np.ndarray:
    """A dense matrix (rows, cols) float64 from an ASCII or binary DMAT file."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise RigError("weights file not found", path=path) from None
    first_end = data.find(b"\n")
    try:
        cols, rows = (int(x) for x in data[:first_end].split())
    except ValueError:
        raise RigError("first line must be 'cols rows'", path=path, line=1, field="header") from None
    if cols == 0 and rows == 0:  # binary: second header line, then raw float64
        second_end = data.find(b"\n", first_end + 1)
        try:
            cols, rows = (int(x) for x in data[first_end + 1:second_end].split())
        except ValueError:
            raise RigError("binary DMAT: second line must be 'cols rows'", path=path, line=2,
                           field="header") from None
        body = data[second_end + 1:]
        if len(body) != 8 * rows * cols:
            raise RigError(f"binary DMAT has {len(body)} bytes of data, header says {rows}x{cols} doubles",
                           path=path, field="data")
        return np.frombuffer(body, "<f8").reshape(cols, rows).T.copy()
    if cols < 0 or rows < 0:
        raise RigError(f"negative size {cols} {rows}", path=path, line=1, field="header")
    try:
        values = np.array(data[first_end + 1:].split(), np.float64)
    except ValueError:
        raise RigError("entries must be numbers", path=path, field="data") from None
    if len(values) != rows * cols:
        raise RigError(f"{len(values)} entries, header says {rows} rows x {cols} columns",
                       path=path, field="data")
    return values.reshape(cols, rows).T.copy()


def write_dmat(path, matrix: np.ndarray) -> None:
    """Write (rows, cols) as ASCII DMAT."""
    matrix = np.atleast_2d(np.asarray(matrix, np.float64))
    rows, cols = matrix.shape
    body = "\n".join(repr(float(x)) for x in matrix.T.reshape(-1))
    Path(path).write_text(f"{cols} {rows}\n{body}\n")
