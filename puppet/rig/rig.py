"""Rig: a character (mesh, skeleton, weights) joined to its servo map, and its constraint pattern.

Bone classification, fixed once per rig:
- *sensed*: the bone has a joint driven by servos, or it is declared ``fixed`` (held rigidly to
  its parent or, for a root, to the stand: identity joint rotation).
- *full*: sensed, and every ancestor is full; its whole transform comes from forward kinematics.
- *relative*: sensed, with a free bone somewhere above it: only its rotation relative to its
  parent is known (FAST couples the two handles at the joint pivot).
- *free*: not sensed (e.g. a flexible spine or tail); the solver decides it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet.fast.pattern import Pattern, PoseFill, Values, full_and_relative
from puppet.rig.calibration import Calibration
from puppet.rig.errors import RigError
from puppet.rig.servo_map import ServoMap
from puppet.rig.skeleton import Skeleton
from puppet.rig.solve_options import SolveExtras
from puppet.rig.source_scene import SourceScene
from puppet.rig.weight_check import WeightReport, check_weights



@dataclass(frozen=True)
class SolverOptions:
    """Options the rig hands to ``puppet.fast.FastModel``.

    clusters:      number of rotation clusters r (k-means in weight space).
    extra_weights: number of extra (free) weight functions.
    energy:        one of ENERGIES.
    """

    clusters: int = 100
    extra_weights: int = 0
    energy: str = "spokes_and_rims"


@dataclass
class Rig:
    """A character ready for the solver, the renderer and the bus.

    name:           rig name.
    V:              (n, 3) float64 rest vertices, model units.
    F:              (f, 3) int32 triangles.
    skeleton:       bones and the servo map's joints (dof i = servo i).
    W:              (n, bones) float64 weights, column j = bone j = solver handle j.
    servo_map:      servos in bus order.
    calibration:    zero ticks in use (also applied to ``servo_map``).
    solver_options: clusters, extra weights, energy.
    pins:           (p,) int64 vertex indices held at their rest positions.
    fixed:          names of bones declared fixed (sensed, identity joint).
    path:           the file the rig was loaded from, if any.
    extras:         live-solve options (dropout handling, dynamics, contacts as written).
    contacts:       (vertex, axes, (x, y, z) targets) per-axis constraints (see set_extras).
    source_index:   (n_source,) int64 or None: for each vertex of the character file, in the
                    file's own order, its index in ``V`` (the loader welds copies that the file
                    split at UV seams). None means the file's order is ``V``'s. Exports that must
                    match the source file (PC2) write ``deformed[source_index]``.
    source:         the glTF character file's look and place (``puppet.rig.source_scene.
                    SourceScene``: attributes, materials, nodes), carried by exports; None for
                    characters that are not glTF.
    files:          every file the rig was read from besides ``path`` (character, its buffers
                    and images, skeleton, weights, calibration): no output may be one of them
                    (``puppet.rig.rig_file.loaded_files``). Set by the loaders, also for a rig
                    read from the text a take stores (whose ``path`` is only a label).
    """

    name: str
    V: np.ndarray
    F: np.ndarray
    skeleton: Skeleton
    W: np.ndarray
    servo_map: ServoMap
    calibration: Calibration = field(default_factory=Calibration)
    solver_options: SolverOptions = field(default_factory=SolverOptions)
    pins: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    fixed: tuple[str, ...] = ()
    path: Path | None = None
    source_index: np.ndarray | None = None
    extras: SolveExtras = field(default_factory=SolveExtras)
    contacts: tuple[tuple[int, str, tuple[float, float, float]], ...] = ()
    source: SourceScene | None = None
    files: tuple[Path, ...] = ()

    def __post_init__(self) -> None:
        self.V = np.ascontiguousarray(self.V, np.float64)
        self.F = np.ascontiguousarray(self.F, np.int32)
        self.W = np.ascontiguousarray(self.W, np.float64)
        self.pins = np.asarray(self.pins, np.int64).reshape(-1)
        n = len(self.V)
        if self.V.ndim != 2 or self.V.shape[1] != 3 or n == 0:
            raise RigError(f"vertices have shape {self.V.shape}, expected (n, 3) with n > 0",
                           path=self.path, field="mesh")
        if not np.isfinite(self.V).all():
            bad = int(np.flatnonzero(~np.isfinite(self.V).all(axis=1))[0])
            raise RigError(f"vertex {bad} is not finite: {self.V[bad].tolist()}", path=self.path,
                           field="mesh")
        if self.F.ndim != 2 or self.F.shape[1] != 3 or (len(self.F) and (self.F.min() < 0 or self.F.max() >= n)):
            raise RigError(f"triangles must be (f, 3) indices below {n}", path=self.path, field="mesh")
        if self.W.shape != (n, self.skeleton.bone_count):
            raise RigError(f"weights have shape {self.W.shape}, mesh has {n} vertices and "
                           f"skeleton {self.skeleton.bone_count} bones", path=self.path, field="weights")
        if not np.isfinite(self.W).all():
            bad = int(np.flatnonzero(~np.isfinite(self.W).all(axis=1))[0])
            raise RigError(f"weights of vertex {bad} are not finite", path=self.path, field="weights")
        bad_pins = self.pins[(self.pins < 0) | (self.pins >= n)]
        if len(bad_pins):
            raise RigError(f"pin vertex {int(bad_pins[0])} out of range (mesh has {n} vertices)",
                           path=self.path, field="pin")
        for name in self.fixed:
            if name not in self.skeleton.names:
                raise RigError(f"unknown fixed bone {name!r}; bones are {list(self.skeleton.names)}",
                               path=self.path, field="fixed")
        self.skeleton = self.skeleton.with_joints(self.servo_map.joints(self.skeleton))
        self.servo_map.calibrate(self.calibration)
        self._classify()
        self._check_actuators()
        b = self.skeleton.bone_count
        self._rotations = np.empty((b, 3, 3))
        self._pose = np.empty((b, 3, 4))
        self._fill: PoseFill | None = None

    def set_extras(self, extras: SolveExtras) -> None:
        """Adopt the rig file's live-solve options; contacts resolve to vertices here (a point
        takes the nearest vertex; a missing value takes the rest coordinate)."""
        n = len(self.V)
        contacts = []
        for i, c in enumerate(extras.contacts):
            if c.vertex is not None:
                if c.vertex >= n:
                    raise RigError(f"vertex {c.vertex} out of range: mesh has {n} vertices",
                                   path=self.path, line=c.line, field=f"contact {i + 1} vertex")
                v = c.vertex
            else:
                v = int(np.argmin(((self.V - np.asarray(c.point)) ** 2).sum(axis=1)))
            target = self.V[v].copy()
            for axis, value in zip(c.axes, c.values):
                if value is not None:
                    target["xyz".index(axis)] = value
            contacts.append((v, c.axes, tuple(float(x) for x in target)))
        for i, lim in enumerate(extras.limits):
            if lim.bone not in self.skeleton.names:
                raise RigError(f"unknown bone {lim.bone!r}; bones are {list(self.skeleton.names)}",
                               path=self.path, line=lim.line, field=f"limit {i + 1} bone")
        self.extras = extras
        self.contacts = tuple(contacts)

    def limits_for(self, free: np.ndarray) -> tuple:
        """Pattern.limits entries for the ``[[limit]]`` bones that are free ((b,) bool mask)."""
        sk = self.skeleton
        out = []
        for lim in self.extras.limits:
            j = sk.index(lim.bone)
            p = int(sk.parents[j])
            if p < 0 or not free[j]:
                continue
            d = np.asarray(sk.tails[j], np.float64) - np.asarray(sk.heads[j], np.float64)
            d = tuple(float(x) for x in d / np.linalg.norm(d))
            lo, hi = lim.twist_deg
            out.append((j, p, d, float(np.radians(lim.swing_deg)), float(np.radians(lo)), float(np.radians(hi))))
        return tuple(out)

    # ---- classification -------------------------------------------------------------------
    def _classify(self) -> None:
        sk = self.skeleton
        sensed = np.zeros(sk.bone_count, bool)
        for j in sk.joints:
            sensed[j.bone] = True
        for name in self.fixed:
            sensed[sk.index(name)] = True
        self.sensed = sensed
        self.full_bones, self.relative_bones = full_and_relative(sk.parents, sensed)
        self.free_bones = np.flatnonzero(~sensed)

    def _check_actuators(self) -> None:
        """RigError naming the servo, joint and line of an actuator on a sensed joint (an
        actuator drives a joint the solve fills in: free or relative, never one a sensor or
        ``fixed`` holds)."""
        sk = self.skeleton
        for s in self.servo_map.actuators:
            bone = sk.index(s.joint)
            if self.sensed[bone]:
                why = "declared fixed" if s.joint in self.fixed else "read by a sensor servo"
                raise RigError(f"actuator servo {s.id} sits on joint {s.joint!r}, which is sensed "
                               f"({why}); an actuator drives a joint the solve fills in (free or "
                               "relative)", path=self.path, line=s.line or None,
                               field=f"servo {s.id} role")

    def bone_kinds(self) -> dict[str, list[str]]:
        """{'full': [...], 'relative': [...], 'free': [...]} bone names."""
        names = self.skeleton.names
        return {"full": [names[i] for i in self.full_bones],
                "relative": [names[i] for i in self.relative_bones],
                "free": [names[i] for i in self.free_bones]}

    def anchor_problem(self) -> str | None:
        """What is wrong when nothing holds the character in space, else None.

        The solve needs a bone whose whole chain to the root is sensed or ``fixed`` (a full
        bone), or a pinned vertex; otherwise the global translation is free and the solver
        cannot factor its constraint pattern.
        """
        if len(self.full_bones) or len(self.pins):
            return None
        root = self.skeleton.names[int(np.flatnonzero(self.skeleton.parents < 0)[0])]
        return (f"nothing holds the character in space: the root bone {root!r} is free (no servo "
                f"on it and not fixed) and no vertex is pinned; add fixed = [\"{root}\"] or a "
                "[[pin]] table (vertex = INDEX or point = [x, y, z])")

    def check_weights(self) -> WeightReport:
        return check_weights(self.W, len(self.V), self.skeleton.names)

    # ---- constraint pattern and per-frame values -------------------------------------------
    def pattern(self, free: frozenset = frozenset()) -> Pattern:
        """The solver's constraint pattern (handle j = bone j; extra weights come after), with
        the bones in ``free`` (indices) solved instead of sensed: bones below them that were
        full become relative. The one place a rig's pattern is built (the loop's LiveSolve asks
        for each pattern it needs through this)."""
        sk = self.skeleton
        sensed = self.sensed
        if free:
            sensed = sensed.copy()
            sensed[sorted(free)] = False
        full, relative = full_and_relative(sk.parents, sensed) if free else \
            (self.full_bones, self.relative_bones)
        return Pattern(full=tuple(int(j) for j in full),
                       relative=tuple((int(c), int(sk.parents[c]), tuple(float(x) for x in sk.heads[c]))
                                      for c in relative),
                       positional=tuple(int(v) for v in self.pins),
                       contacts=tuple((v, axes) for v, axes, _ in self.contacts),
                       limits=self.limits_for(~sensed))

    def contact_targets(self) -> np.ndarray:
        """(c, 3) float64 target coordinates of the rig's contacts, in ``pattern().contacts`` order."""
        return np.array([target for _, _, target in self.contacts], np.float64).reshape(-1, 3)

    def fill_values(self, angles: np.ndarray, values: Values) -> None:
        """Write ``self.pattern().values()`` for these angles ((k,) radians, servo-map order):
        full blocks ``[A_jᵀ; t_jᵀ]`` from forward kinematics, relative entries the joint
        rotation, pins their rest positions, contacts their targets. The same fill as the
        loop's (``puppet.fast.pattern.PoseFill``), for one-off solves and tests."""
        if self._fill is None:
            self._fill = PoseFill(self.pattern())
        rot = self.skeleton.joint_rotations(angles, self._rotations)
        pose = self.skeleton.pose_from_rotations(rot, self._pose)
        self._fill.fill(values, rot, pose)
        values.positional[:] = self.V[self.pins]
        values.contact[:] = self.contact_targets()

    def pose(self, angles: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Forward kinematics of every bone, (bones, 3, 4); see :meth:`Skeleton.pose`."""
        return self.skeleton.pose(angles, out)
