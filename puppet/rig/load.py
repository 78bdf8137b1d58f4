"""Loading rigs: a TOML rig file (servo map naming its character files), a glTF file, or the
built-in character."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from puppet.rig.calibration import Calibration
from puppet.rig.errors import RigError
from puppet.rig.rig import Rig
from puppet.rig.rig_file import read_rig_file
from puppet.rig.servo_map import ServoMap
from puppet.rig.skeleton import Skeleton
from puppet.rig.weight_check import normalize_weights

BUILTIN_RIG = Path(__file__).resolve().parent / "builtin" / "critter.toml"
CHARACTER_KEYS = ("V", "F", "W", "names", "parents", "heads", "tails", "frames")


def builtin() -> Rig:
    """The built-in character "critter" (precomputed weights; loads in well under 2 s)."""
    return load_rig(BUILTIN_RIG)


def read_character_npz(path):
    """(V, F, W, skeleton) from the compact .npz character format written by
    ``puppet/rig/builtin/make_character.py`` (keys: CHARACTER_KEYS)."""
    path = Path(path)
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
    skeleton = Skeleton(tuple(str(n) for n in arrays["names"]), arrays["parents"], arrays["heads"],
                        arrays["tails"], arrays["frames"])
    W = normalize_weights(arrays["W"], path=path, field_name="W")
    return arrays["V"].astype(np.float64), arrays["F"].astype(np.int32), W, skeleton


def _read_character(spec):
    """(V, F, W, skeleton, source_index) for a rig file's mesh/skeleton/weights entries
    (source_index: see ``Rig.source_index``)."""
    from puppet.rig.tgf_dmat import read_dmat, read_tgf

    suffix = spec.mesh.suffix.lower()
    if suffix == ".npz":
        return (*read_character_npz(spec.mesh), None)
    if suffix in (".glb", ".gltf"):
        from puppet.rig.gltf import read_gltf

        character = read_gltf(spec.mesh, skin=spec.skin)
        return character.V, character.F, character.W, character.skeleton, character.source_index
    if suffix in (".obj", ".ply"):
        from puppet.rig.mesh_io import read_mesh

        V, F = read_mesh(spec.mesh)
        if spec.skeleton is None:
            raise RigError("an .obj/.ply mesh needs 'skeleton = \"....tgf\"'", path=spec.path, field="skeleton")
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
        return V, F, W, skeleton, None
    raise RigError(f"unknown character format {suffix!r} (known: .npz, .glb, .gltf, .obj, .ply)",
                   path=spec.path, field="mesh")


def load_rig(path) -> Rig:
    """Load a rig: a TOML rig file, or a bare .glb/.gltf/.npz character (no servos)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".glb", ".gltf"):
        from puppet.rig.gltf import read_gltf

        c = read_gltf(path)
        return Rig(path.stem, c.V, c.F, c.skeleton, c.W, ServoMap([], path=path), path=path,
                   source_index=c.source_index)
    if suffix == ".npz":
        V, F, W, skeleton = read_character_npz(path)
        return Rig(path.stem, V, F, skeleton, W, ServoMap([], path=path), path=path)
    if suffix != ".toml":
        raise RigError(f"unknown rig format {suffix!r} (known: .toml, .glb, .gltf, .npz)", path=path)
    spec = read_rig_file(path)
    V, F, W, skeleton, source_index = _read_character(spec)
    pins = []
    for vertex, line in spec.pin_vertices:
        if vertex >= len(V):
            raise RigError(f"pin vertex {vertex} out of range: mesh has {len(V)} vertices",
                           path=path, line=line, field="pin vertex")
        pins.append(vertex)
    for point, _ in spec.pin_points:
        pins.append(int(np.argmin(((V - point) ** 2).sum(axis=1))))
    if spec.calibration is not None and spec.calibration.exists():
        calibration = Calibration.load(spec.calibration)
    else:
        calibration = Calibration(path=spec.calibration)
    # Joint errors (unknown joint, >3 servos, repeated order) name the rig file's line.
    rig = Rig(spec.name, V, F, skeleton, W, spec.servo_map, calibration, spec.solver,
              np.array(pins, np.int64), spec.fixed, path, source_index)
    rig.set_extras(spec.extras)
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
