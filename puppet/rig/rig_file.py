"""The rig file (TOML): which character files, which servos, pins and solver options.

Example (paths are relative to the rig file)::

    name = "critter"
    mesh = "critter.npz"          # .npz (built-in format), .glb/.gltf, or .obj/.ply with:
    # skin = 0                    #   (.glb/.gltf with several skins: which one)
    # skeleton = "body.tgf"       #   a libigl TGF skeleton, and optionally
    # weights = "body.dmat"       #   DMAT weights (else bounded biharmonic weights, cached)
    calibration = "critter.calibration.toml"   # optional, host-side zero ticks
    fixed = ["hips"]              # bones held rigidly (sensed, identity joint)

    [solver]
    clusters = 100
    extra_weights = 8
    energy = "spokes_and_rims"    # spokes | spokes_and_rims | elements

    [[servo]]
    id = 1
    model = "XL330-M288"
    joint = "neck"                # bone name
    axis = "x"                    # x | y | z | -x ... or [ax, ay, az] in the bone's rest frame
    order = 1                     # composition order within the joint
    sign = 1
    gear = 1.0
    zero_ticks = 2048
    limits_deg = [-60, 60]

    [[pin]]
    vertex = 1234                 # or point = [x, y, z]: the nearest vertex
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet.rig.errors import RigError
from puppet.rig.rig import ENERGIES, SolverOptions
from puppet.rig.servo_map import X_SERIES_MODELS, Servo, ServoMap
from puppet.rig.solve_options import SolveExtras, read_solve_extras

NAMED_AXES = {"x": (1.0, 0, 0), "y": (0, 1.0, 0), "z": (0, 0, 1.0)}
SERVO_KEYS = {"id", "model", "joint", "axis", "order", "sign", "gear", "zero_ticks", "limits_deg"}
TOP_KEYS = {"name", "mesh", "skin", "skeleton", "weights", "calibration", "fixed", "solver", "servo",
            "pin"}


class _Lines:
    """Finds the line of a table or key in TOML text (tomllib reports values, not lines)."""

    _header = re.compile(r"^\s*\[\[?\s*([A-Za-z0-9_.\-]+)\s*\]\]?")
    _key = re.compile(r"^\s*([A-Za-z0-9_\-]+)\s*=")

    def __init__(self, text: str) -> None:
        self.tables: dict[tuple[str, int], int] = {}
        self.keys: dict[tuple[str, int, str], int] = {}
        current, counts = ("", 0), {"": 0}
        for number, line in enumerate(text.splitlines(), 1):
            header = self._header.match(line)
            if header:
                name = header.group(1)
                counts[name] = counts.get(name, -1) + 1
                current = (name, counts[name])
                self.tables[current] = number
                continue
            key = self._key.match(line)
            if key:
                self.keys.setdefault((*current, key.group(1)), number)

    def table(self, name: str, index: int) -> int | None:
        return self.tables.get((name, index))

    def key(self, table: str, index: int, key: str) -> int | None:
        return self.keys.get((table, index, key)) or self.table(table, index)


@dataclass
class RigFile:
    """A parsed, validated rig file; mesh paths are absolute."""

    path: Path
    name: str
    mesh: Path
    skeleton: Path | None
    weights: Path | None
    calibration: Path | None
    fixed: tuple[str, ...]
    solver: SolverOptions
    servo_map: ServoMap
    pin_vertices: list[tuple[int, int]] = field(default_factory=list)   # (vertex, line)
    pin_points: list[tuple[np.ndarray, int]] = field(default_factory=list)  # (point, line)
    skin: int | None = None       # glTF skin index; None: the file's only skin
    extras: SolveExtras = field(default_factory=SolveExtras)  # contacts, dynamics, dropout


def read_rig_file(path) -> RigFile:
    """Parse and validate a rig TOML file; every error names the file and the line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RigError("rig file not found", path=path) from None
    except (OSError, UnicodeDecodeError) as err:
        raise RigError(f"cannot read rig file: {err}", path=path) from err
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise RigError(f"not valid TOML: {err}", path=path) from err
    lines = _Lines(text)

    def fail(message, field_name, line):
        raise RigError(message, path=path, field=field_name, line=line)

    extras = read_solve_extras(doc, lines, fail)  # takes its own keys out of doc
    for key in doc:
        if key not in TOP_KEYS:
            fail(f"unknown key (known: {sorted(TOP_KEYS)})", key, lines.key("", 0, key))

    def file_key(key, required):
        value = doc.get(key)
        if value is None:
            if required:
                fail("missing (the character's mesh file)", key, None)
            return None
        if not isinstance(value, str) or not value:
            fail(f"must be a file path, got {value!r}", key, lines.key("", 0, key))
        return (path.parent / value).resolve()

    mesh = file_key("mesh", True)
    skeleton, weights, calibration = file_key("skeleton", False), file_key("weights", False), \
        file_key("calibration", False)
    name = doc.get("name", path.stem)
    if not isinstance(name, str):
        fail(f"must be a string, got {name!r}", "name", lines.key("", 0, "name"))
    skin = doc.get("skin")
    if skin is not None and (isinstance(skin, bool) or not isinstance(skin, int) or skin < 0):
        fail(f"must be a glTF skin index >= 0, got {skin!r}", "skin", lines.key("", 0, "skin"))
    fixed = doc.get("fixed", [])
    if not isinstance(fixed, list) or not all(isinstance(f, str) for f in fixed):
        fail(f"must be a list of bone names, got {fixed!r}", "fixed", lines.key("", 0, "fixed"))

    solver = _read_solver(doc.get("solver", {}), lines, fail)
    servos = doc.get("servo", [])
    if not isinstance(servos, list):
        fail("must be an array of tables [[servo]]", "servo", lines.key("", 0, "servo"))
    parsed = [_read_servo(i, s, lines, fail) for i, s in enumerate(servos)]
    servo_map = ServoMap(parsed, path=path)

    pin_vertices, pin_points = [], []
    for i, pin in enumerate(doc.get("pin", [])):
        line = lines.table("pin", i)
        if "vertex" in pin:
            v = pin["vertex"]
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                fail(f"must be a vertex index >= 0, got {v!r}", f"pin {i + 1} vertex", line)
            pin_vertices.append((v, line))
        elif "point" in pin:
            pin_points.append((_vector(pin["point"], f"pin {i + 1} point", line, fail), line))
        else:
            fail("needs 'vertex' or 'point'", f"pin {i + 1}", line)
    return RigFile(path, name, mesh, skeleton, weights, calibration, tuple(fixed), solver,
                   servo_map, pin_vertices, pin_points, skin, extras)


def _read_solver(table, lines, fail) -> SolverOptions:
    if not isinstance(table, dict):
        fail("must be a table [solver]", "solver", lines.key("", 0, "solver"))
    defaults = SolverOptions()
    clusters = table.get("clusters", defaults.clusters)
    extra = table.get("extra_weights", defaults.extra_weights)
    energy = table.get("energy", defaults.energy)
    for key in table:
        if key not in ("clusters", "extra_weights", "energy"):
            fail("unknown solver option (known: clusters, extra_weights, energy)",
                 f"solver.{key}", lines.key("solver", 0, key))
    if isinstance(clusters, bool) or not isinstance(clusters, int) or clusters < 1:
        fail(f"must be an integer >= 1, got {clusters!r}", "solver.clusters", lines.key("solver", 0, "clusters"))
    if isinstance(extra, bool) or not isinstance(extra, int) or extra < 0:
        fail(f"must be an integer >= 0, got {extra!r}", "solver.extra_weights",
             lines.key("solver", 0, "extra_weights"))
    if energy not in ENERGIES:
        fail(f"unknown energy {energy!r} (known: {', '.join(ENERGIES)})", "solver.energy",
             lines.key("solver", 0, "energy"))
    return SolverOptions(clusters, extra, energy)


def _vector(value, field_name, line, fail) -> np.ndarray:
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)):
        fail(f"must be three numbers, got {value!r}", field_name, line)
    return np.array(value, np.float64)


def _read_servo(index: int, table: dict, lines: _Lines, fail) -> Servo:
    header = lines.table("servo", index)
    label = f"servo #{index + 1}"
    servo_id = table.get("id")
    if isinstance(servo_id, bool) or not isinstance(servo_id, int) or not 0 <= servo_id <= 252:
        fail(f"id must be an integer 0..252, got {servo_id!r}", f"{label} id", lines.key("servo", index, "id"))
    label = f"servo {servo_id}"

    def line(key):
        return lines.key("servo", index, key)

    for key in table:
        if key not in SERVO_KEYS:
            fail(f"unknown key (known: {sorted(SERVO_KEYS)})", f"{label} {key}", line(key))
    model = table.get("model")
    if model not in X_SERIES_MODELS:
        fail(f"unknown model {model!r} (known: {', '.join(X_SERIES_MODELS)})", f"{label} model", line("model"))
    joint = table.get("joint")
    if not isinstance(joint, str) or not joint:
        fail(f"joint must be a bone name, got {joint!r}", f"{label} joint", line("joint"))
    raw_axis = table.get("axis")
    if isinstance(raw_axis, str):
        key = raw_axis.strip().lower()
        negative = key.startswith("-")
        if key.lstrip("+-") not in NAMED_AXES:
            fail(f"axis must be x, y, z (optionally signed) or three numbers, got {raw_axis!r}",
                 f"{label} axis", line("axis"))
        axis = np.array(NAMED_AXES[key.lstrip("+-")]) * (-1.0 if negative else 1.0)
    else:
        axis = _vector(raw_axis, f"{label} axis", line("axis"), fail)
    norm = float(np.linalg.norm(axis))
    if norm < 1e-9:
        fail(f"axis {raw_axis!r} has zero length", f"{label} axis", line("axis"))
    order = table.get("order", 1)
    if isinstance(order, bool) or not isinstance(order, int) or not 1 <= order <= 3:
        fail(f"order must be 1, 2 or 3, got {order!r}", f"{label} order", line("order"))
    sign = table.get("sign", 1)
    if sign not in (1, -1) or isinstance(sign, bool):
        fail(f"sign must be 1 or -1, got {sign!r}", f"{label} sign", line("sign"))
    gear = table.get("gear", 1.0)
    if isinstance(gear, bool) or not isinstance(gear, (int, float)) or not gear > 0:
        fail(f"gear must be a number > 0, got {gear!r}", f"{label} gear", line("gear"))
    zero = table.get("zero_ticks", 2048)
    if isinstance(zero, bool) or not isinstance(zero, int):
        fail(f"zero_ticks must be an integer, got {zero!r}", f"{label} zero_ticks", line("zero_ticks"))
    limits = table.get("limits_deg", [-180.0, 180.0])
    if (not isinstance(limits, list) or len(limits) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in limits)):
        fail(f"limits_deg must be [low, high] degrees, got {limits!r}", f"{label} limits_deg", line("limits_deg"))
    if not limits[0] < limits[1]:
        fail(f"limits reversed or empty: low {limits[0]} >= high {limits[1]}", f"{label} limits_deg",
             line("limits_deg"))
    return Servo(servo_id, model, joint, axis / norm, order, sign, float(gear), zero,
                 (float(np.radians(limits[0])), float(np.radians(limits[1]))), header or 0)
