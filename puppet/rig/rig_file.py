"""The rig file (TOML): which character files, which servos, pins and solver options.

Example (paths are relative to the rig file)::

    name = "critter"
    mesh = "critter.npz"          # .npz (built-in format), .glb/.gltf, or .obj/.ply with:
    # skin = 0                    #   (.glb/.gltf with several skins: which one)
    # skeleton = "body.tgf"       #   a libigl TGF skeleton, and optionally
    # weights = "body.dmat"       #   DMAT weights (else bounded biharmonic weights, cached)
    calibration = "critter.calibration.toml"   # optional, host-side zero ticks; without it,
                                  # <rig file's name>.calibration.toml beside the rig file when
                                  # it exists (where `puppet calibrate` writes the zero ticks)
    fixed = ["hips"]              # bones held rigidly (sensed, identity joint)

    [solver]
    clusters = 100                # 1 .. MAX_CLUSTERS, and at most the mesh's vertex count
    extra_weights = 8             # 0 .. MAX_EXTRA_WEIGHTS
    energy = "spokes_and_rims"    # spokes | spokes_and_rims | elements

    [[servo]]
    id = 1                        # 0 .. 252
    model = "XL330-M288"          # one of puppet.servo_models.MODELS
    joint = "neck"                # bone name
    axis = "x"                    # x | y | z | -x ... or [ax, ay, az] in the bone's rest frame
    order = 1                     # composition order within the joint
    sign = 1                      # 1 or -1
    gear = 1.0                    # servo turns per joint turn, GEAR_RANGE
    zero_ticks = 2048             # ticks at the rest pose (int32; default the middle of the
                                  # model's positions: 2048, or 512 on AX / RX / XL-320)
    limits_deg = [-60, 60]        # low < high, within +-LIMIT_RANGE_DEG; on a model with a
                                  # dead zone (AX / RX / XL-320) inside its 300° (servo_map)

    [[pin]]                       # at most 4 per handle (load.PINS_PER_HANDLE), < vertex count
    vertex = 1234                 # or point = [x, y, z] (COORD): the nearest vertex

Every number must lie in its documented range (puppet.limits.Range; the constants below and in
puppet/rig/solve_options.py): TOML's ``nan`` and ``inf`` are refused, and so is anything finite
but absurd. Every error is a RigError naming the file, the line of the key (or of its table), the
field, the value and the range.
"""

from __future__ import annotations

import math
import os
import re
import reprlib
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet.fast.energy_names import ENERGIES
from puppet.limits import Range
from puppet.rig.errors import RigError, check_regular_file
from puppet.rig.rig import SolverOptions
from puppet.rig.servo_map import GEAR_RANGE, INT32, ROLES, Servo, ServoMap
from puppet.rig.solve_options import COORD, VERTEX, SolveExtras, read_solve_extras
from puppet.servo_models import MODELS, known_models

NAMED_AXES = {"x": (1.0, 0, 0), "y": (0, 1.0, 0), "z": (0, 0, 1.0)}
SERVO_KEYS = {"id", "model", "joint", "axis", "order", "sign", "gear", "zero_ticks", "limits_deg",
              "role"}
PIN_KEYS = {"vertex", "point"}
SOLVER_KEYS = {"clusters", "extra_weights", "energy"}
TOP_KEYS = {"name", "mesh", "skin", "skeleton", "weights", "calibration", "fixed", "solver", "servo", "pin"}

LIMIT_RANGE_DEG = 360.0
"""Joint limits lie within +-one turn of the rest pose (servo_map.LIMIT_RANGE, in degrees)."""
LIMIT_DEG = Range(-LIMIT_RANGE_DEG, LIMIT_RANGE_DEG, "degrees")
MAX_CLUSTERS = 5000
"""Rotation clusters; also at most the mesh's vertex count (checked when the mesh is read)."""
CLUSTERS = Range(1, MAX_CLUSTERS, integer=True)
MAX_EXTRA_WEIGHTS = 200
"""Extra (free) weight functions: each adds a handle to every per-frame solve."""
EXTRA_WEIGHTS = Range(0, MAX_EXTRA_WEIGHTS, integer=True)
SERVO_ID = Range(0, 252, integer=True)
"""Dynamixel ids (253.. are reserved, 254 is broadcast)."""
ORDER = Range(1, 3, integer=True)
GEAR = Range(*GEAR_RANGE, "servo turns per joint turn")
ZERO_TICKS = Range(*INT32, "ticks", integer=True)
SKIN = Range(0, 1_000_000, integer=True)
MAX_PATH_LENGTH = 4096

_show = reprlib.Repr()
_show.maxlevel, _show.maxstring, _show.maxother, _show.maxlist = 2, 40, 40, 4


def show(value) -> str:
    """A short repr for error messages (deeply nested or huge values stay short)."""
    return _show.repr(value)


class _Lines:
    """Finds the line of a table or key in TOML text (tomllib reports values, not lines)."""

    _header = re.compile(r"^\s*\[\[?\s*([A-Za-z_][A-Za-z0-9_.\-]*)\s*\]\]?\s*(#.*)?$")
    _key = re.compile(r"^\s*([A-Za-z0-9_\-]+)\s*=")

    def __init__(self, text: str) -> None:
        self.tables: dict[tuple[str, int], int] = {}
        self.roots: dict[str, int] = {}  # first line of any table under a top-level name
        self.keys: dict[tuple[str, int, str], int] = {}
        current, counts = ("", 0), {"": 0}
        for number, line in enumerate(text.splitlines(), 1):
            header = self._header.match(line)
            if header:
                name = header.group(1)
                counts[name] = counts.get(name, -1) + 1
                current = (name, counts[name])
                self.tables[current] = number
                self.roots.setdefault(name.split(".")[0], number)
                continue
            key = self._key.match(line)
            if key:
                self.keys.setdefault((*current, key.group(1)), number)

    def table(self, name: str, index: int = 0) -> int | None:
        return self.tables.get((name, index))

    def key(self, table: str, index: int, key: str) -> int | None:
        return self.keys.get((table, index, key)) or self.table(table, index)

    def top(self, key: str) -> int | None:
        """Line of a top-level key, or of the table of that name."""
        return self.keys.get(("", 0, key)) or self.table(key, 0) or self.roots.get(key)


@dataclass
class RigFile:
    """A parsed, validated rig file; character paths are absolute.

    path:         the rig file (or a label such as "take.mcap (rig map)" for text from a take).
    lines:        where each key is, for errors found after the character is read
                  (``lines.top("fixed")``, ``lines.key("solver", 0, "clusters")``).
    pin_vertices: [(vertex index, line of the key)]; pin_points: [((3,) float64 point, line)].
    """

    path: Path
    name: str
    mesh: Path
    skeleton: Path | None
    weights: Path | None
    calibration: Path | None
    fixed: tuple[str, ...]
    solver: SolverOptions
    servo_map: ServoMap
    pin_vertices: list[tuple[int, int]] = field(default_factory=list)
    pin_points: list[tuple[np.ndarray, int]] = field(default_factory=list)
    lines: _Lines | None = None
    skin: int | None = None       # glTF skin index; None: the file's only skin
    extras: SolveExtras = field(default_factory=SolveExtras)  # contacts, dynamics, dropout


def read_rig_file(path) -> RigFile:
    """Parse and validate a rig TOML file; every error names the file and the line."""
    path = Path(path)
    check_regular_file(path, "rig file")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise RigError("rig file not found", path=path) from None
    except IsADirectoryError:
        raise RigError("is a folder, not a rig file", path=path) from None
    except OSError as err:
        raise RigError(f"cannot read rig file: {err.strerror or err}", path=path) from err
    if raw.startswith(b"\xef\xbb\xbf"):  # a byte-order mark (Windows editors): not TOML
        raw = raw[3:]
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[:err.start].count(b"\n") + 1
        raise RigError(f"not UTF-8 text (byte 0x{raw[err.start]:02x} at offset {err.start}); "
                       "a rig file is TOML", path=path, line=line) from None
    spec = read_rig_text(text, path=path, base=path.parent)
    if spec.calibration is None and default_calibration(path).is_file():
        spec.calibration = Path(os.path.abspath(default_calibration(path)))
    return spec


def default_calibration(rig_path) -> Path:
    """The calibration file of a rig file that names none: ``<name>.calibration.toml`` beside
    it (``my.toml`` -> ``my.calibration.toml``); read when it exists, written by ``puppet
    calibrate``."""
    rig_path = Path(rig_path)
    return rig_path.with_name(f"{rig_path.stem}.calibration.toml")


_TOML_LINE = re.compile(r"\(at line (\d+), column \d+\)|\(at end of document\)")


def read_rig_text(text: str, *, path, base) -> RigFile:
    """Parse and validate rig TOML ``text``; character files are resolved relative to ``base``.

    path: what errors name (the rig file, or e.g. "take.mcap (rig map)").
    """
    base = Path(base)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        found = _TOML_LINE.search(str(err))
        message = _TOML_LINE.sub("", str(err)).strip()
        line = None
        if found:  # tomllib names a line and column, or the end of the text
            line = int(found.group(1)) if found.group(1) else max(1, len(text.splitlines()))
        raise RigError(f"not valid TOML: {message}", path=path, line=line) from None
    except RecursionError:
        raise RigError("not a rig file: tables or arrays nested too deeply", path=path) from None
    lines = _Lines(text)

    def fail(message, field_name, line):
        raise RigError(message, path=path, field=field_name, line=line)

    extras = read_solve_extras(doc, lines, fail)  # takes its own keys out of doc
    for key in doc:
        if key not in TOP_KEYS:
            fail(f"unknown key (known: {', '.join(sorted(TOP_KEYS))})", key, lines.top(key))

    def file_key(key, required):
        value = doc.get(key)
        if value is None:
            if required:
                fail("missing: the character's mesh file (e.g. mesh = \"creature.glb\")", key, None)
            return None
        if (not isinstance(value, str) or not value.strip() or "\0" in value
                or len(value) > MAX_PATH_LENGTH):
            fail(f"must be a file path, got {show(value)}", key, lines.top(key))
        return Path(os.path.abspath(base / value))

    mesh = file_key("mesh", True)
    skeleton, weights, calibration = file_key("skeleton", False), file_key("weights", False), \
        file_key("calibration", False)
    name = doc.get("name", Path(str(path)).stem)
    if not isinstance(name, str) or not name:
        fail(f"must be a non-empty string, got {show(name)}", "name", lines.top("name"))
    skin = doc.get("skin")
    if skin is not None and not SKIN.holds(skin):
        fail(f"a glTF skin index {SKIN.problem(skin)}", "skin", lines.top("skin"))
    fixed = doc.get("fixed", [])
    if not isinstance(fixed, list) or not all(isinstance(f, str) and f for f in fixed):
        fail(f"must be a list of bone names, got {show(fixed)}", "fixed", lines.top("fixed"))
    if len(set(fixed)) != len(fixed):
        fail(f"a bone is listed twice in {show(fixed)}", "fixed", lines.top("fixed"))

    solver = _read_solver(doc.get("solver", {}), lines, fail)
    servos = doc.get("servo", [])
    if not isinstance(servos, list) or not all(isinstance(s, dict) for s in servos):
        fail("must be an array of tables [[servo]]", "servo", lines.top("servo"))
    parsed = [_read_servo(i, s, lines, fail) for i, s in enumerate(servos)]
    servo_map = ServoMap(parsed, path=path)
    _check_contradictions(mesh, skin, fixed, parsed, extras, lines, fail)

    pins = doc.get("pin", [])
    if not isinstance(pins, list) or not all(isinstance(p, dict) for p in pins):
        fail("must be an array of tables [[pin]]", "pin", lines.top("pin"))
    pin_vertices, pin_points = [], []
    for i, pin in enumerate(pins):
        line = lines.table("pin", i)
        label = f"pin #{i + 1}"
        for key in pin:
            if key not in PIN_KEYS:
                fail(f"unknown key (known: {', '.join(sorted(PIN_KEYS))})", f"{label} {key}",
                     lines.key("pin", i, key))
        if len(pin) != 1:
            fail("needs exactly one of 'vertex = INDEX' or 'point = [x, y, z]'", label, line)
        if "vertex" in pin:
            v = pin["vertex"]
            if not VERTEX.holds(v):
                fail(f"a vertex index {VERTEX.problem(v)}", f"{label} vertex",
                     lines.key("pin", i, "vertex"))
            pin_vertices.append((v, lines.key("pin", i, "vertex")))
        else:
            at = lines.key("pin", i, "point")
            pin_points.append((_vector(pin["point"], f"{label} point", at, fail), at))
    return RigFile(Path(str(path)), name, mesh, skeleton, weights, calibration, tuple(fixed),
                   solver, servo_map, pin_vertices, pin_points, lines, skin, extras)


def _check_contradictions(mesh: Path, skin, fixed, servos, extras, lines: _Lines, fail) -> None:
    """Refuse keys that contradict each other, naming the line of the later one: a servo on a
    bone declared fixed (held rigidly: it has no joint to read or drive), ``skin`` on a mesh
    that is not glTF, a ``[[limit]]`` on a fixed bone or on a bone a sensor servo reads (limits
    bound what the solve decides), two ``[[limit]]`` on one bone. (Two servos about one axis
    of a joint: ``ServoMap.joints``.)"""
    for i, servo in enumerate(servos):
        if servo.joint in fixed:
            fail(f"servo {servo.id} is on joint {servo.joint!r}, which 'fixed' (line "
                 f"{lines.top('fixed')}) holds rigidly: a fixed bone has no joint to "
                 f"{'drive' if servo.role == 'actuator' else 'read'}; remove the bone from "
                 "'fixed' or the servo", f"servo #{i + 1} joint", lines.key("servo", i, "joint"))
    if skin is not None and mesh.suffix.lower() not in (".glb", ".gltf"):
        fail(f"'skin' picks one of a glTF file's skins, but the mesh {mesh.name} is not glTF "
             "(.glb/.gltf): remove 'skin'", "skin", lines.top("skin"))
    sensed = {servo.joint: servo.id for servo in servos if servo.role != "actuator"}
    seen: dict[str, int | None] = {}
    for limit in extras.limits:
        if limit.bone in fixed:
            fail(f"limit on bone {limit.bone!r}, which 'fixed' holds rigidly: limits bound a "
                 "bone the solve decides; remove the limit", "limit", limit.line)
        if limit.bone in sensed:
            fail(f"limit on bone {limit.bone!r}, which servo {sensed[limit.bone]} reads: limits "
                 "bound a bone the solve decides (a servo's own range is its limits_deg); "
                 "remove the limit", "limit", limit.line)
        if limit.bone in seen:
            fail(f"a second limit on bone {limit.bone!r} (the first is on line "
                 f"{seen[limit.bone]}): one [[limit]] per bone", "limit", limit.line)
        seen[limit.bone] = limit.line


def _read_solver(table, lines, fail) -> SolverOptions:
    if not isinstance(table, dict):
        fail("must be a table [solver]", "solver", lines.top("solver"))
    defaults = SolverOptions()
    for key in table:
        if key not in SOLVER_KEYS:
            fail(f"unknown solver option (known: {', '.join(sorted(SOLVER_KEYS))})",
                 f"solver.{key}", lines.key("solver", 0, key))
    clusters = table.get("clusters", defaults.clusters)
    extra = table.get("extra_weights", defaults.extra_weights)
    energy = table.get("energy", defaults.energy)
    if not CLUSTERS.holds(clusters):
        fail(f"{CLUSTERS.problem(clusters)} (and at most the mesh's vertex count)",
             "solver.clusters", lines.key("solver", 0, "clusters"))
    if not EXTRA_WEIGHTS.holds(extra):
        fail(EXTRA_WEIGHTS.problem(extra), "solver.extra_weights",
             lines.key("solver", 0, "extra_weights"))
    if not isinstance(energy, str) or energy not in ENERGIES:
        fail(f"unknown energy {show(energy)} (known: {', '.join(ENERGIES)})", "solver.energy",
             lines.key("solver", 0, "energy"))
    return SolverOptions(clusters, extra, energy)


def _vector(value, field_name, line, fail) -> np.ndarray:
    """Three numbers, each within COORD (model units)."""
    if not isinstance(value, list) or len(value) != 3 or not all(map(COORD.holds, value)):
        fail(f"must be three numbers, each {COORD}, got {show(value)}", field_name, line)
    return np.array(value, np.float64)


def _read_servo(index: int, table: dict, lines: _Lines, fail) -> Servo:
    header = lines.table("servo", index)
    label = f"servo #{index + 1}"

    def line(key):
        return lines.key("servo", index, key)

    servo_id = table.get("id")
    if not SERVO_ID.holds(servo_id):
        fail(f"id {SERVO_ID.problem(servo_id)}", f"{label} id", line("id"))
    label = f"servo {servo_id}"
    for key in table:
        if key not in SERVO_KEYS:
            fail(f"unknown key (known: {', '.join(sorted(SERVO_KEYS))})", f"{label} {key}", line(key))
    model = table.get("model")
    if not isinstance(model, str) or model not in MODELS:
        fail(f"unknown model {show(model)} (known: {known_models()})", f"{label} model",
             line("model"))
    joint = table.get("joint")
    if not isinstance(joint, str) or not joint:
        fail(f"joint must be a bone name, got {show(joint)}", f"{label} joint", line("joint"))
    raw_axis = table.get("axis")
    if isinstance(raw_axis, str):
        key = raw_axis.strip().lower()
        negative = key.startswith("-")
        if key.lstrip("+-") not in NAMED_AXES or len(key) > 2:
            fail(f"axis must be x, y, z (optionally signed) or three numbers, got {show(raw_axis)}",
                 f"{label} axis", line("axis"))
        axis = np.array(NAMED_AXES[key.lstrip("+-")]) * (-1.0 if negative else 1.0)
    else:
        axis = _vector(raw_axis, f"{label} axis", line("axis"), fail)
    norm = math.hypot(*axis)  # no overflow for huge but finite components
    if not 1e-9 < norm < math.inf:
        fail(f"axis {show(raw_axis)} has zero length or is not finite", f"{label} axis", line("axis"))
    order = table.get("order", 1)
    if not ORDER.holds(order):
        fail(f"order {ORDER.problem(order)}", f"{label} order", line("order"))
    sign = table.get("sign", 1)
    if isinstance(sign, bool) or not isinstance(sign, int) or sign not in (1, -1):
        fail(f"sign must be 1 or -1, got {show(sign)}", f"{label} sign", line("sign"))
    gear = table.get("gear", 1.0)
    if not GEAR.holds(gear):
        fail(f"gear {GEAR.problem(gear)} (use sign = -1 to reverse)", f"{label} gear", line("gear"))
    zero = table.get("zero_ticks", getattr(MODELS.get(model), "position_ticks", 4096) // 2)
    if not ZERO_TICKS.holds(zero):
        fail(f"zero_ticks {ZERO_TICKS.problem(zero)}", f"{label} zero_ticks", line("zero_ticks"))
    limits = table.get("limits_deg", [-180.0, 180.0])
    if not isinstance(limits, list) or len(limits) != 2 or not all(map(LIMIT_DEG.holds, limits)):
        fail(f"limits_deg must be [low, high], each {LIMIT_DEG}, got {show(limits)}",
             f"{label} limits_deg", line("limits_deg"))
    if not limits[0] < limits[1]:
        fail(f"limits reversed or empty: low {limits[0]} >= high {limits[1]}", f"{label} limits_deg",
             line("limits_deg"))
    role = table.get("role", "sensor")
    if role not in ROLES:
        fail(f"role must be one of {', '.join(ROLES)}, got {show(role)}", f"{label} role", line("role"))
    return Servo(servo_id, model, joint, axis / norm, order, sign, float(gear), zero,
                 (float(np.radians(limits[0])), float(np.radians(limits[1]))), header or 0, role)


def character_files(character) -> list[Path]:
    """A character file and what it names: a glTF's buffers and images (resolved next to it)."""
    from puppet.rig.gltf import external_files

    character = Path(character)
    files = [character]
    if character.suffix.lower() in (".gltf", ".glb"):
        files += external_files(character)
    return files


def spec_files(spec: RigFile) -> list[Path]:
    """Every file a parsed rig file makes the loader read (not the rig file itself): its
    character (``character_files``), skeleton, weights and calibration files."""
    files = character_files(spec.mesh)
    return files + [p for p in (spec.skeleton, spec.weights, spec.calibration) if p is not None]


def input_files(path) -> list[Path]:
    """Every file loading the rig at ``path`` reads: the rig file, its character, skeleton,
    weights and calibration files, and a glTF character's buffers and images (outputs may be
    none of them). ``path``: a rig file (.toml) or a bare character file."""
    path = Path(path)
    if path.suffix.lower() == ".toml":
        return [path, *spec_files(read_rig_file(path))]
    return character_files(path)


def loaded_files(rig) -> list[Path]:
    """Every file a loaded rig was read from, which no output of a command using it may be: its
    path, its ``files`` (set by the loaders: character, buffers, images, skeleton, weights,
    calibration; also for the rig a take stores) and its calibration file now. [] for a rig made
    in memory. The one list of a rig's inputs: a command's other inputs (the take, and the sound
    and session files to come) are added by ``puppet.replay.take_inputs``."""
    files = [Path(rig.path)] if getattr(rig, "path", None) is not None else []
    files += list(getattr(rig, "files", ()))
    calibration = getattr(getattr(rig, "calibration", None), "path", None)
    return list(dict.fromkeys(files + ([Path(calibration)] if calibration is not None else [])))
