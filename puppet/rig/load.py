"""Loading rigs: a TOML rig file (servo map naming its character files), a glTF file, or the
built-in character."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from puppet.rig.calibration import Calibration
from puppet.rig.errors import RigError, check_regular_file
from puppet.rig.rig import Rig
from puppet.rig.rig_file import RigFile, character_files, read_rig_file, read_rig_text, spec_files
from puppet.rig.servo_map import ServoMap
from puppet.rig.skeleton import Skeleton
from puppet.rig.weight_check import normalize_weights

BUILTIN_RIG = Path(__file__).resolve().parent / "builtin" / "critter.toml"
BUILTIN_DYNAMICS_RIG = BUILTIN_RIG.with_name("critter_dynamics.toml")
"""The built-in character with secondary motion ([solver.dynamics]: ears and tail lag, settle)."""
BUILTIN_AX_RIG = BUILTIN_RIG.with_name("critter_ax.toml")
"""The built-in character on one Protocol 1.0 bus: AX-12A servos (ids 1..8) and MX-28 (9..15)."""
CHARACTER_KEYS = ("V", "F", "W", "names", "parents", "heads", "tails", "frames")


def builtin() -> Rig:
    """The built-in character "critter" (precomputed weights; loads in well under 2 s)."""
    return load_rig(BUILTIN_RIG)


PINS_PER_HANDLE = 4
"""Pins a rig may hold per handle (bone or extra weight): four points fix an affine handle, so
more can only over-determine the solve (documented beside [[pin]] in rig_file.py)."""


def read_character_npz(path):
    """(V, F, W, skeleton) from the compact .npz character format written by
    ``puppet/rig/builtin/make_character.py`` (keys: CHARACTER_KEYS)."""
    path = Path(path)
    check_regular_file(path, "character file")
    if not path.exists():
        raise RigError("character file not found", path=path)
    if not zipfile.is_zipfile(path):
        raise RigError("not a character .npz: not a zip archive (an .npz is written by "
                       "numpy.savez)", path=path)
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in CHARACTER_KEYS if k not in data.files]
            if missing:
                raise RigError(f"missing arrays {missing}", path=path, field="npz")
            arrays = {k: data[k] for k in CHARACTER_KEYS}
    except FileNotFoundError:
        raise RigError("character file not found", path=path) from None
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise RigError(f"not a character .npz: {err}", path=path) from err
    for key in ("V", "W", "heads", "tails", "frames"):
        if not np.issubdtype(arrays[key].dtype, np.number) or not np.isfinite(arrays[key]).all():
            raise RigError("not all finite numbers", path=path, field=key)
    try:
        skeleton = Skeleton(tuple(str(n) for n in arrays["names"]), arrays["parents"],
                            arrays["heads"], arrays["tails"], arrays["frames"])
    except RigError as err:
        raise err.at(path) from None
    except (ValueError, TypeError) as err:  # arrays of the wrong shape or kind
        raise RigError(f"skeleton arrays unusable: {err}", path=path, field="skeleton") from None
    W = normalize_weights(arrays["W"], path=path, field_name="W")
    return arrays["V"].astype(np.float64), arrays["F"].astype(np.int32), W, skeleton


def _read_character(spec):
    """(V, F, W, skeleton, source_index, source) for a rig file's mesh/skeleton/weights entries
    (source_index, source: see ``Rig``)."""
    from puppet.rig.tgf_dmat import read_dmat, read_tgf

    for what, path in (("mesh", spec.mesh), ("skeleton", spec.skeleton), ("weights", spec.weights),
                       ("calibration", spec.calibration)):
        if path is not None:
            check_regular_file(path, f"{what} file")
    suffix = spec.mesh.suffix.lower()
    if suffix == ".npz":
        return (*read_character_npz(spec.mesh), None, None)
    if suffix in (".glb", ".gltf"):
        from puppet.rig.gltf import read_gltf

        character = read_gltf(spec.mesh, skin=spec.skin)
        return (character.V, character.F, character.W, character.skeleton, character.source_index,
                character.source)
    if suffix in (".obj", ".ply"):
        from puppet.rig.mesh_io import read_mesh

        V, F = read_mesh(spec.mesh)
        if spec.skeleton is None:
            raise RigError("an .obj/.ply mesh needs 'skeleton = \"....tgf\"'", path=spec.path,
                           field="skeleton", line=spec.lines.top("mesh") if spec.lines else None)
        skeleton, columns = read_tgf(spec.skeleton)
        if spec.weights is not None:
            raw = read_dmat(spec.weights)
            if raw.shape != (len(V), skeleton.bone_count):
                raise RigError(f"{raw.shape[0]} rows x {raw.shape[1]} columns, mesh has {len(V)} vertices "
                               f"and skeleton {skeleton.bone_count} handles", path=spec.weights, field="weights")
            W = normalize_weights(raw[:, columns], path=spec.weights)
        else:
            from puppet.rig.bbw import bbw_weights

            W = bbw_weights(V, F, skeleton, path=spec.mesh)
        return V, F, W, skeleton, None, None
    raise RigError(f"unknown character format {suffix!r} (known: .npz, .glb, .gltf, .obj, .ply)",
                   path=spec.path, field="mesh", line=spec.lines.top("mesh") if spec.lines else None)


def load_rig(path) -> Rig:
    """Load a rig: a TOML rig file, or a bare .glb/.gltf/.npz character (no servos)."""
    path = Path(path)
    suffix = path.suffix.lower()
    check_regular_file(path, "rig file" if suffix == ".toml" else "character file")
    if suffix in (".glb", ".gltf"):
        from puppet.rig.gltf import read_gltf

        c = read_gltf(path)
        return Rig(path.stem, c.V, c.F, c.skeleton, c.W, ServoMap([], path=path), path=path,
                   source_index=c.source_index, source=c.source, files=tuple(character_files(path)))
    if suffix == ".npz":
        V, F, W, skeleton = read_character_npz(path)
        return Rig(path.stem, V, F, skeleton, W, ServoMap([], path=path), path=path,
                   files=(path,))
    if suffix != ".toml":
        raise RigError(f"unknown rig format {suffix!r} (known: .toml, .glb, .gltf, .npz)", path=path)
    return rig_from_spec(read_rig_file(path))


def load_rig_text(text: str, *, label, bases, hint: str = "") -> Rig:
    """A rig from rig-file TOML held in memory (e.g. the rig map a take stores).

    label: what errors name (e.g. "take.mcap (rig map)"). bases: folders to resolve the text's
    relative character paths against, tried in order: the first where the mesh file exists
    wins. RigError naming the mesh and every place looked (then ``hint``) when none has it.
    """
    bases = list(dict.fromkeys(Path(b) for b in bases))
    tried = []
    for base in bases:
        spec = read_rig_text(text, path=label, base=base)
        if spec.mesh.exists():
            return rig_from_spec(spec)
        tried.append(str(spec.mesh))
    raise RigError(f"character file not found: looked at {' and '.join(tried)}"
                   + (f"; {hint}" if hint else ""), path=label, field="mesh",
                   line=spec.lines.top("mesh") if spec.lines else None)


def builtin_name() -> str:
    """The built-in rig's name, from its file (no character is read)."""
    return read_rig_file(BUILTIN_RIG).name


def rig_from_spec(spec: RigFile) -> Rig:
    """Read a parsed rig file's character and join it to the servo map.

    Errors found only once the character is known (pins out of range, unknown fixed bones, more
    clusters than vertices, nothing holding the character in space) name the rig file's line.
    """
    path, lines = spec.path, spec.lines
    V, F, W, skeleton, source_index, source = _read_character(spec)
    n = len(V)

    def fail(message, field_name, line):
        raise RigError(message, path=path, field=field_name, line=line)

    pins: list[int] = []
    where: dict[int, int] = {}
    for vertex, line in spec.pin_vertices:
        if vertex >= n:
            fail(f"pin vertex {vertex} out of range: the mesh has {n} vertices", "pin vertex", line)
        pins.append(vertex)
        where.setdefault(vertex, line)
    for point, line in spec.pin_points:
        pins.append(int(np.argmin(((V - point) ** 2).sum(axis=1))))
        where.setdefault(pins[-1], line)
    seen: set[int] = set()
    for i, vertex in enumerate(pins):
        if vertex in seen:
            line = (spec.pin_vertices + spec.pin_points)[i][1]
            fail(f"vertex {vertex} is pinned twice (first at line {where[vertex]})", "pin", line)
        seen.add(vertex)
    handles = skeleton.bone_count + spec.solver.extra_weights
    most = min(n - 1, PINS_PER_HANDLE * handles)
    if len(pins) > most:
        fail(f"{len(pins)} pins; at most {most}: {PINS_PER_HANDLE} per handle ({handles} handles: "
             f"bones and extra weights), and fewer than the mesh's {n} vertices (more pins "
             "over-determine the solve)", "pin", lines.top("pin") if lines else None)
    for name in spec.fixed:
        if name not in skeleton.names:
            fail(f"unknown fixed bone {name!r}; bones are {list(skeleton.names)}", "fixed",
                 lines.top("fixed") if lines else None)
    opts = spec.solver
    if opts.clusters > n:
        fail(f"{opts.clusters} clusters but the mesh has only {n} vertices", "solver.clusters",
             lines.key("solver", 0, "clusters") if lines else None)
    if opts.extra_weights > n:
        fail(f"{opts.extra_weights} extra weights but the mesh has only {n} vertices",
             "solver.extra_weights", lines.key("solver", 0, "extra_weights") if lines else None)
    if spec.calibration is not None and spec.calibration.exists():
        calibration = Calibration.load(spec.calibration)
    else:
        calibration = Calibration(path=spec.calibration)
    # Joint errors (unknown joint, >3 servos, repeated order) name the rig file's line.
    rig = Rig(spec.name, V, F, skeleton, W, spec.servo_map, calibration, spec.solver,
              np.array(pins, np.int64), spec.fixed, path, source_index, source=source,
              files=tuple(spec_files(spec)))
    rig.set_extras(spec.extras)
    problem = rig.anchor_problem()
    if problem is not None:
        line = lines.top("fixed") if lines else None
        fail(problem, "fixed", line)
    _check_placeable(rig)
    return rig


#: A bone whose weight never exceeds this moves no vertex.
NO_INFLUENCE = 1e-6


def _check_placeable(rig: Rig) -> None:
    """RigError when a free bone moves no vertex: the solve has nothing to place it by (glTF
    exports often carry such bones: control or IK bones). Holding it (fixed) or sensing it
    (a servo) places it from its parent."""
    lonely = [rig.skeleton.names[b] for b in rig.free_bones if rig.W[:, b].max() <= NO_INFLUENCE]
    if lonely:
        raise RigError(f"bones {lonely} influence no vertex and nothing holds them, so the solve cannot "
                       "place them: add them to 'fixed' (or give them a servo)", path=rig.path, field="fixed")
