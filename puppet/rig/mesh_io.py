"""Triangle mesh files: Wavefront OBJ and Stanford PLY (ASCII and binary), read into
V (n, 3) float64 and F (f, 3) int32. Polygons are fan-triangulated. Errors name the file and
the line or element at fault."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from puppet.rig.errors import RigError


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Read an .obj or .ply mesh by suffix."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        return read_obj(path)
    if suffix == ".ply":
        return read_ply(path)
    raise RigError(f"unknown mesh format {suffix!r} (known: .obj, .ply)", path=path)


def _check_faces(V, F, path) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(V, np.float64).reshape(-1, 3)
    F = np.asarray(F, np.int64).reshape(-1, 3)
    if len(F) == 0:
        raise RigError("mesh has no triangles", path=path, field="faces")
    if F.min() < 0 or F.max() >= len(V):
        bad = int(np.flatnonzero((F < 0).any(1) | (F >= len(V)).any(1))[0])
        raise RigError(f"face {bad} references vertex {F[bad].tolist()}, mesh has {len(V)} vertices",
                       path=path, field=f"face {bad}")
    if not np.isfinite(V).all():
        bad = int(np.flatnonzero(~np.isfinite(V).all(1))[0])
        raise RigError("vertex coordinate is not finite", path=path, field=f"vertex {bad}")
    return V, F.astype(np.int32)


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="strict")
    except FileNotFoundError:
        raise RigError("file not found", path=path) from None
    except (OSError, UnicodeDecodeError) as err:
        raise RigError(f"cannot read: {err}", path=path) from err


def read_obj(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ('v') and faces ('f', 1-based or negative, 'v/vt/vn' tokens) of an OBJ file."""
    path = Path(path)
    vertices, faces = [], []
    for number, line in enumerate(_read_text(path).splitlines(), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        if parts[0] == "v":
            try:
                vertices.append([float(x) for x in parts[1:4]])
            except ValueError:
                raise RigError(f"bad vertex {line.strip()!r}", path=path, line=number, field="v") from None
            if len(vertices[-1]) != 3:
                raise RigError("vertex needs x y z", path=path, line=number, field="v")
        elif parts[0] == "f":
            try:
                idx = [int(token.split("/")[0]) for token in parts[1:]]
            except ValueError:
                raise RigError(f"bad face {line.strip()!r}", path=path, line=number, field="f") from None
            if len(idx) < 3 or 0 in idx:
                raise RigError("face needs 3+ vertex indices (1-based)", path=path, line=number, field="f")
            n = len(vertices)
            idx = [i - 1 if i > 0 else n + i for i in idx]
            if min(idx) < 0 or max(idx) >= n:
                raise RigError(f"face references a vertex not yet defined ({n} so far)", path=path,
                               line=number, field="f")
            faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    return _check_faces(vertices, faces, path)


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (x, y, z) and faces (vertex_indices list) of an ASCII or binary PLY file."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise RigError("file not found", path=path) from None
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise RigError("not a PLY file (no 'ply' magic or no 'end_header')", path=path, field="header")
    body_start = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt, elements = None, []
    for number, line in enumerate(header, 1):
        parts = line.split()
        if not parts or parts[0] in ("ply", "comment", "obj_info"):
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property":
            if not elements:
                raise RigError("property before any element", path=path, line=number, field="header")
            if parts[1] == "list":
                if parts[2] not in _PLY_TYPES or parts[3] not in _PLY_TYPES:
                    raise RigError(f"unknown list type in {line!r}", path=path, line=number, field="header")
                elements[-1][2].append((parts[4], (_PLY_TYPES[parts[2]], _PLY_TYPES[parts[3]])))
            else:
                if parts[1] not in _PLY_TYPES:
                    raise RigError(f"unknown property type {parts[1]!r}", path=path, line=number, field="header")
                elements[-1][2].append((parts[2], _PLY_TYPES[parts[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise RigError(f"unknown format {fmt!r}", path=path, field="header format")
    names = [e[0] for e in elements]
    if "vertex" not in names or "face" not in names:
        raise RigError(f"needs 'vertex' and 'face' elements, has {names}", path=path, field="header")
    vertex_props = [p[0] for p in elements[names.index("vertex")][2]]
    for axis in "xyz":
        if axis not in vertex_props:
            raise RigError(f"vertex element has no '{axis}' property", path=path, field="vertex")
    if fmt == "ascii":
        parsed = _ply_ascii(data[body_start:].decode("ascii", errors="replace"), elements, path)
    else:
        parsed = _ply_binary(data, body_start, elements, "<" if fmt.endswith("little_endian") else ">", path)
    vertex, face = parsed["vertex"], parsed["face"]
    V = np.column_stack([vertex["x"], vertex["y"], vertex["z"]])
    lists = face.get("vertex_indices", face.get("vertex_index"))
    if lists is None:
        raise RigError("face element has no 'vertex_indices' list", path=path, field="face")
    tris = [[poly[0], poly[k], poly[k + 1]] for poly in lists for k in range(1, len(poly) - 1)]
    return _check_faces(V, tris, path)


def _ply_ascii(text, elements, path):
    tokens = iter(text.split())
    out = {}
    for name, count, props in elements:
        columns = {p[0]: [] for p in props}
        for row in range(count):
            try:
                for prop, kind in props:
                    if isinstance(kind, tuple):
                        n = int(next(tokens))
                        columns[prop].append([int(float(next(tokens))) for _ in range(n)])
                    else:
                        columns[prop].append(float(next(tokens)))
            except (StopIteration, ValueError):
                raise RigError("truncated or malformed data", path=path, field=f"{name} {row}") from None
        out[name] = columns
    return out


def _ply_binary(data, offset, elements, endian, path):
    out = {}
    for name, count, props in elements:
        if all(not isinstance(kind, tuple) for _, kind in props):
            dtype = np.dtype([(p, endian + k) for p, k in props])
            if offset + dtype.itemsize * count > len(data):
                raise RigError(f"file ends inside element '{name}'", path=path, field=name)
            table = np.frombuffer(data, dtype, count, offset)
            offset += dtype.itemsize * count
            out[name] = {p: table[p].astype(np.float64) for p, _ in props}
            continue
        columns = {p[0]: [] for p in props}
        for row in range(count):
            for prop, kind in props:
                try:
                    if isinstance(kind, tuple):
                        count_type, item_type = np.dtype(endian + kind[0]), np.dtype(endian + kind[1])
                        n = int(np.frombuffer(data, count_type, 1, offset)[0])
                        offset += count_type.itemsize
                        columns[prop].append(np.frombuffer(data, item_type, n, offset).astype(np.int64).tolist())
                        offset += item_type.itemsize * n
                    else:
                        t = np.dtype(endian + kind)
                        columns[prop].append(float(np.frombuffer(data, t, 1, offset)[0]))
                        offset += t.itemsize
                except ValueError:
                    raise RigError("file ends inside the element", path=path, field=f"{name} {row}") from None
        out[name] = columns
    return out
