"""Rig-file sections for the live solve: ground contacts, secondary motion and dropout handling.

Read by ``read_rig_file`` (it hands the parsed TOML document over first; these keys are taken
out of it). Example::

    on_dropout = "free"           # hold (default): a silent servo keeps its last angle;
    dropout_ms = 150              #   free: after this long its bones are solved (0..60000 ms)
    dropout_blend_frames = 6      # frames over which a switch (either way) is blended (1..120)

    [[servo]]
    id = 3
    on_dropout = "hold"           # per-servo override
    ...

    [solver.dynamics]             # secondary motion: inertia, damping, gravity
    density = 0.002               # mass per unit area (DENSITY: 0..1000): larger lags longer
    damping = 0.9                 # 0 (no momentum) .. 1 (full momentum)
    gravity = [0, -9.81, 0]       # model units / s^2, each -1e5..1e5 (default: none)
    dt = 0.016666                 # solver time step, seconds (DT: 0.0001..1); frames take
    max_steps = 4                 #   round(elapsed / dt) steps (from the reading times), 1..64

    [[contact]]                   # per-axis positional constraint (e.g. a foot on the floor)
    vertex = 1234                 # or point = [x, y, z] (COORD): the nearest vertex
    axes = "y"                    # any of x, y, z: the coordinates held; the others stay free
    value = 0.0                   # one number per axis (or one for all), COORD; default: rest

    [[limit]]                     # joint limit of a free (solved) bone, relative to its parent
    bone = "chest"
    swing_deg = 20                # cone half-angle about the bone's rest direction, 0..180
    twist_deg = [-15, 15]         # twist about it, [min, max], within -180..180

Every number is checked against the Range declared below (puppet.limits); errors name the field,
the value and the range.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from puppet.limits import Range

DROPOUT_MODES = ("hold", "free")
TOP_KEYS = ("on_dropout", "dropout_ms", "dropout_blend_frames", "contact", "limit")
DYNAMICS_KEYS = ("density", "damping", "gravity", "dt", "max_steps")
CONTACT_KEYS = ("vertex", "point", "axes", "value")
LIMIT_KEYS = ("bone", "swing_deg", "twist_deg")

COORD = Range(-1e6, 1e6, "model units")
"""A point or coordinate of the character (contacts, pins)."""
VERTEX = Range(0, 2**31 - 1, integer=True)
"""A vertex index (and less than the mesh's vertex count, checked when the mesh is read)."""
DROPOUT_MS = Range(0, 60_000, "ms")
BLEND_FRAMES = Range(1, 120, "frames", integer=True)
DENSITY = Range(0, 1000, "mass per unit area")
DAMPING = Range(0, 1)
GRAVITY = Range(-1e5, 1e5, "model units/s^2")
DT = Range(1e-4, 1.0, "s")
MAX_STEPS = Range(1, 64, integer=True)
SWING_DEG = Range(0, 180, "degrees")
TWIST_DEG = Range(-180, 180, "degrees")


@dataclass(frozen=True)
class ContactSpec:
    """One ``[[contact]]``: vertex index or rest point (nearest vertex), axes ('xyz' subset),
    values per axis (None: the rest coordinate), and its line in the rig file (of ``vertex``)."""

    vertex: int | None
    point: tuple[float, float, float] | None
    axes: str
    values: tuple[float | None, ...]
    line: int | None


@dataclass(frozen=True)
class LimitSpec:
    """One ``[[limit]]``: bone name, swing cone half-angle and twist range (degrees), line."""

    bone: str
    swing_deg: float
    twist_deg: tuple[float, float]
    line: int | None


@dataclass(frozen=True)
class DynamicsOptions:
    """``[solver.dynamics]``: see puppet.fast.Dynamics (dt seconds, density >= 0, damping 0..1,
    gravity model units / s^2); max_steps caps the solver steps one frame may take."""

    density: float = 0.002
    damping: float = 0.9
    gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dt: float = 1.0 / 60.0
    max_steps: int = 4


@dataclass(frozen=True)
class SolveExtras:
    """The live-solve options of a rig (all optional; the defaults change nothing).

    on_dropout:     "hold" or "free" for every servo, unless overridden in ``servo_dropout``.
    servo_dropout:  {servo id: "hold" | "free"} per-servo overrides.
    dropout_ms:     how long a servo must be flagged before its bones become free.
    blend_frames:   frames over which a pattern switch is blended (both ways).
    dynamics:       secondary motion, or None.
    contacts:       ``[[contact]]`` entries in file order.
    limits:         ``[[limit]]`` entries (joint limits of free bones).
    """

    on_dropout: str = "hold"
    servo_dropout: dict[int, str] = field(default_factory=dict)
    dropout_ms: float = 150.0
    blend_frames: int = 6
    dynamics: DynamicsOptions | None = None
    contacts: tuple[ContactSpec, ...] = ()
    limits: tuple[LimitSpec, ...] = ()

    def dropout_mode(self, servo_id: int) -> str:
        return self.servo_dropout.get(servo_id, self.on_dropout)

    @property
    def frees_on_dropout(self) -> bool:
        return self.on_dropout == "free" or "free" in self.servo_dropout.values()


def read_solve_extras(doc: dict, lines, fail) -> SolveExtras:
    """Take this module's keys out of the parsed rig document ``doc`` (in place) and validate them.

    lines: the rig file's line finder (``lines.key(table, index, key)``); fail(message, field,
    line) raises the RigError naming the file and line."""
    mode = doc.pop("on_dropout", "hold")
    if mode not in DROPOUT_MODES:
        fail(f"must be one of {', '.join(DROPOUT_MODES)}, got {mode!r}", "on_dropout",
             lines.key("", 0, "on_dropout"))
    ms = doc.pop("dropout_ms", 150.0)
    if not DROPOUT_MS.holds(ms):
        fail(DROPOUT_MS.problem(ms), "dropout_ms", lines.key("", 0, "dropout_ms"))
    blend = doc.pop("dropout_blend_frames", 6)
    if not BLEND_FRAMES.holds(blend):
        fail(BLEND_FRAMES.problem(blend), "dropout_blend_frames",
             lines.key("", 0, "dropout_blend_frames"))
    servo_dropout = {}
    servos = doc.get("servo", [])
    if isinstance(servos, list):
        for i, servo in enumerate(servos):
            if isinstance(servo, dict) and "on_dropout" in servo:
                value = servo.pop("on_dropout")
                if value not in DROPOUT_MODES:
                    fail(f"on_dropout must be one of {', '.join(DROPOUT_MODES)}, got {value!r}",
                         f"servo {servo.get('id', i + 1)} on_dropout", lines.key("servo", i, "on_dropout"))
                servo_dropout[servo.get("id")] = value
    dynamics = None
    solver = doc.get("solver")
    if isinstance(solver, dict) and "dynamics" in solver:
        dynamics = _read_dynamics(solver.pop("dynamics"), lines, fail)
    contacts = doc.pop("contact", [])
    if not isinstance(contacts, list) or not all(isinstance(c, dict) for c in contacts):
        fail("must be an array of tables [[contact]]", "contact", lines.key("", 0, "contact"))
    parsed = tuple(_read_contact(i, c, lines, fail) for i, c in enumerate(contacts))
    limits = doc.pop("limit", [])
    if not isinstance(limits, list) or not all(isinstance(c, dict) for c in limits):
        fail("must be an array of tables [[limit]]", "limit", lines.key("", 0, "limit"))
    limits = tuple(_read_limit(i, t, lines, fail) for i, t in enumerate(limits))
    return SolveExtras(mode, servo_dropout, float(ms), blend, dynamics, parsed, limits)


def _read_limit(index: int, table: dict, lines, fail) -> LimitSpec:
    label = f"limit {index + 1}"

    def line(key):
        return lines.key("limit", index, key)

    for key in table:
        if key not in LIMIT_KEYS:
            fail(f"unknown key (known: {', '.join(LIMIT_KEYS)})", f"{label} {key}", line(key))
    bone = table.get("bone")
    if not isinstance(bone, str) or not bone:
        fail(f"bone must be a bone name, got {bone!r}", f"{label} bone", line("bone"))
    swing = table.get("swing_deg", 180.0)
    if not SWING_DEG.holds(swing):
        fail(f"swing_deg {SWING_DEG.problem(swing)}", f"{label} swing_deg", line("swing_deg"))
    twist = table.get("twist_deg", [-180.0, 180.0])
    if not isinstance(twist, list) or len(twist) != 2 or not all(map(TWIST_DEG.holds, twist)):
        fail(f"twist_deg must be [min, max], each {TWIST_DEG}, got {twist!r}", f"{label} twist_deg",
             line("twist_deg"))
    if twist[0] > twist[1]:
        fail(f"twist_deg min {twist[0]} > max {twist[1]}", f"{label} twist_deg", line("twist_deg"))
    if "swing_deg" not in table and "twist_deg" not in table:
        fail("needs swing_deg and/or twist_deg", label, lines.table("limit", index))
    return LimitSpec(bone, float(swing), (float(twist[0]), float(twist[1])), line("bone"))


def _read_dynamics(table, lines, fail) -> DynamicsOptions:
    where = "solver.dynamics"
    if not isinstance(table, dict):
        fail("must be a table [solver.dynamics]", where, lines.key("solver", 0, "dynamics"))

    def line(key):
        return lines.key(where, 0, key)

    for key in table:
        if key not in DYNAMICS_KEYS:
            fail(f"unknown option (known: {', '.join(DYNAMICS_KEYS)})", f"{where}.{key}", line(key))
    d = DynamicsOptions()
    density = table.get("density", d.density)
    if not DENSITY.holds(density):
        fail(f"density {DENSITY.problem(density)}", f"{where}.density", line("density"))
    damping = table.get("damping", d.damping)
    if not DAMPING.holds(damping):
        fail(f"damping {DAMPING.problem(damping)}", f"{where}.damping", line("damping"))
    gravity = table.get("gravity", list(d.gravity))
    if not isinstance(gravity, list) or len(gravity) != 3 or not all(map(GRAVITY.holds, gravity)):
        fail(f"gravity must be three numbers, each {GRAVITY}, got {gravity!r}", f"{where}.gravity",
             line("gravity"))
    dt = table.get("dt", d.dt)
    if not DT.holds(dt):
        fail(f"time step dt {DT.problem(dt)}", f"{where}.dt", line("dt"))
    steps = table.get("max_steps", d.max_steps)
    if not MAX_STEPS.holds(steps):
        fail(f"max_steps {MAX_STEPS.problem(steps)}", f"{where}.max_steps", line("max_steps"))
    return DynamicsOptions(float(density), float(damping), tuple(float(g) for g in gravity), float(dt), steps)


def _read_contact(index: int, table: dict, lines, fail) -> ContactSpec:
    label = f"contact {index + 1}"
    header = lines.table("contact", index)

    def line(key):
        return lines.key("contact", index, key)

    for key in table:
        if key not in CONTACT_KEYS:
            fail(f"unknown key (known: {', '.join(CONTACT_KEYS)})", f"{label} {key}", line(key))
    vertex = point = None
    if "vertex" in table and "point" in table:
        fail("give 'vertex' or 'point', not both", label, header)
    if "vertex" in table:
        vertex = table["vertex"]
        if not VERTEX.holds(vertex):
            fail(f"a vertex index {VERTEX.problem(vertex)}", f"{label} vertex", line("vertex"))
    elif "point" in table:
        p = table["point"]
        if not isinstance(p, list) or len(p) != 3 or not all(map(COORD.holds, p)):
            fail(f"must be three numbers, each {COORD}, got {p!r}", f"{label} point", line("point"))
        point = tuple(float(x) for x in p)
    else:
        fail("needs 'vertex' or 'point'", label, header)
    axes = table.get("axes")
    if isinstance(axes, list) and all(isinstance(a, str) for a in axes):
        axes = "".join(axes)
    if (not isinstance(axes, str) or not axes or set(axes.lower()) - set("xyz")
            or len(set(axes.lower())) != len(axes)):
        fail(f"axes must be distinct letters of x, y, z (e.g. \"y\" or \"xz\"), got {table.get('axes')!r}",
             f"{label} axes", line("axes"))
    axes = axes.lower()
    raw = table.get("value")
    if raw is None:
        values = (None,) * len(axes)
    elif COORD.holds(raw):
        values = (float(raw),) * len(axes)
    elif isinstance(raw, list) and len(raw) == len(axes) and all(map(COORD.holds, raw)):
        values = tuple(float(x) for x in raw)
    else:
        fail(f"value must be a number or {len(axes)} numbers (one per axis), each {COORD}, "
             f"got {raw!r}",
             f"{label} value", line("value"))
    return ContactSpec(vertex, point, axes, values, line("vertex") if vertex is not None else header)
