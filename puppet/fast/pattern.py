"""Constraint patterns and their per-frame values for the FAST global step.

A *pattern* says which handles are constrained and how; it is fixed per rig (changing it
refactors the solver). *Values* are the per-frame targets for a pattern; changing them
does not refactor.

Layout reminder: T is (4m, 3) float32, rows 4j..4j+3 hold handle j's 3x4 affine transform
transposed, so a rest point p moves to [p 1] @ T[4j:4j+4] under handle j alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from puppet import _kinematics
from puppet.fast.errors import PatternError

POINT_SUM_TOLERANCE = 1e-6
"""How far a surface point's barycentric weights may sum from 1."""


def positional_entry(entry, where: str = "pattern.positional"):
    """One ``Pattern.positional`` entry in its hashable form: a vertex index as ``int``, a surface
    point as ``((v0, v1, v2), (b0, b1, b2))`` of ints and floats (numpy scalars and arrays are
    turned into these). A shape that is neither raises PatternError naming ``where``; ranges and
    weights are checked by :meth:`Pattern.validate`."""
    if isinstance(entry, (int, np.integer)) and not isinstance(entry, bool):
        return int(entry)
    try:
        corners, bary = entry
        corners, bary = np.asarray(corners), np.asarray(bary, np.float64)
    except (TypeError, ValueError):
        corners = bary = None
    if corners is None or corners.shape != (3,) or corners.dtype.kind not in "iu" or bary.shape != (3,):
        raise PatternError(f"{where}: {entry!r} is neither a vertex index nor a surface point "
                           "((v0, v1, v2), (b0, b1, b2))")
    return tuple(int(v) for v in corners), tuple(float(b) for b in bary)


def positional_corners(entries) -> tuple[np.ndarray, np.ndarray]:
    """(corners (k, 3) int64, bary (k, 3) float64) of positional entries: a surface point's
    triangle corners and barycentric weights; a vertex v is the point ((v, v, v), (1, 0, 0)).
    The entry's deformed position is ``sum_c bary[c] V'[corners[c]]``."""
    k = len(entries)
    corners = np.zeros((k, 3), np.int64)
    bary = np.zeros((k, 3), np.float64)
    for q, entry in enumerate(entries):
        if isinstance(entry, (int, np.integer)):
            corners[q] = int(entry)
            bary[q, 0] = 1.0
        else:
            corners[q], bary[q] = entry
    return corners, bary


def _point_key(corners, bary) -> tuple:
    """The point an entry names, whatever the corners' order: its (vertex, weight) pairs with
    repeated corners merged and zero weights dropped (a vertex v is ((v, 1.0),))."""
    weights: dict[int, float] = {}
    for v, b in zip(corners, bary):
        weights[v] = weights.get(v, 0.0) + b
    return tuple(sorted((v, round(b, 9)) for v, b in weights.items() if round(b, 9) != 0.0))


def full_and_relative(parents: np.ndarray, sensed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split the sensed handles of a skeleton into full and relative ones.

    parents: (m,) int, each handle's parent, -1 for roots, parents before children.
    sensed:  (m,) bool, handles whose joint rotation is known each frame.
    -> (full, relative), int64 handle indices, ascending: full are sensed with every ancestor
    full (forward kinematics gives their whole transform); relative are sensed below a handle
    that is not (only their rotation relative to the parent is known).
    """
    full = np.zeros_like(sensed)
    for i, p in enumerate(parents):
        full[i] = sensed[i] and (p < 0 or full[p])
    return np.flatnonzero(full), np.flatnonzero(sensed & ~full)


@dataclass(frozen=True)
class Pattern:
    """Which handles are constrained, and how. Handles not named anywhere are free.

    full:       handle indices whose whole transform is given each frame (12 values each).
    relative:   (child, parent, pivot) triples: child's linear part = parent's linear part
                times a per-frame rotation R, and both handles map the rest point ``pivot``
                ((3,) model units) to the same place.
    positional: points whose deformed position is given each frame, each a vertex index (int)
                or a surface point ((v0, v1, v2), (b0, b1, b2)): the barycentric combination
                sum_k b_k V'[v_k] of a triangle's corners (weights finite, summing to 1; see
                :func:`positional_entry`, :func:`positional_corners`).
    contacts:   (vertex, axes) pairs: the vertex's deformed position is given in the named axes
                only (axes a non-empty string of distinct 'x', 'y', 'z', e.g. "y": a foot at a
                floor height, free to slide in x and z). Each column then gets its own solve.
    limits:     (child, parent, axis, swing_max, twist_min, twist_max) joint limits on free
                handles: the child's rotation relative to the parent (child linear part =
                parent linear part @ R) stays within a cone of half-angle swing_max about the
                unit bone direction ``axis`` (model space, rest) and a twist about it in
                [twist_min, twist_max] (radians). Enforced in every global step (projection).
    """

    full: tuple[int, ...] = ()
    relative: tuple[tuple[int, int, tuple[float, float, float]], ...] = ()
    positional: tuple[int | tuple[tuple[int, int, int], tuple[float, float, float]], ...] = field(default=())
    contacts: tuple[tuple[int, str], ...] = ()
    limits: tuple[tuple[int, int, tuple[float, float, float], float, float, float], ...] = ()

    def validate(self, m: int, n: int) -> None:
        """Raise PatternError unless the pattern fits m handles and n vertices and is consistent:
        indices in range, no handle both full and a relative child, no child constrained twice,
        no handle its own parent, finite pivots, no vertex or point pinned twice, points' corners
        in range and their weights finite and summing to 1."""
        def handle(j, what):
            if not isinstance(j, (int, np.integer)) or not 0 <= int(j) < m:
                raise PatternError(f"pattern.{what}: handle {j!r} is not in 0..{m - 1}")
            return int(j)

        full = [handle(j, "full") for j in self.full]
        if len(set(full)) != len(full):
            raise PatternError(f"pattern.full: handles {sorted(j for j in set(full) if full.count(j) > 1)} repeated")
        children = []
        for q, item in enumerate(self.relative):
            if len(item) != 3:
                raise PatternError(f"pattern.relative[{q}]: expected (child, parent, (px, py, pz)), got {item!r}")
            c, p, pivot = item
            c, p = handle(c, f"relative[{q}] child"), handle(p, f"relative[{q}] parent")
            if c == p:
                raise PatternError(f"pattern.relative[{q}]: handle {c} is its own parent")
            if c in full:
                raise PatternError(f"pattern.relative[{q}]: child {c} is also a full handle")
            piv = np.asarray(pivot, dtype=np.float64)
            if piv.shape != (3,) or not np.isfinite(piv).all():
                raise PatternError(f"pattern.relative[{q}]: pivot {pivot!r} is not 3 finite numbers")
            children.append(c)
        if len(set(children)) != len(children):
            raise PatternError("pattern.relative: a child handle appears in two relative constraints")
        pinned: dict[tuple, int] = {}
        for q, entry in enumerate(self.positional):
            if isinstance(entry, (int, np.integer)) and not isinstance(entry, bool):
                if not 0 <= int(entry) < n:
                    raise PatternError(f"pattern.positional[{q}]: vertex {entry!r} is not in 0..{n - 1}")
                key = ((int(entry), 1.0),)
            else:
                corners, bary = positional_entry(entry, f"pattern.positional[{q}]")
                what = f"pattern.positional[{q}] (point {corners}, {bary})"
                bad = [v for v in corners if not 0 <= v < n]
                if bad:
                    raise PatternError(f"{what}: corner vertex {bad[0]} is not in 0..{n - 1}")
                if not np.isfinite(bary).all():
                    raise PatternError(f"{what}: barycentric weights must be finite")
                if abs(sum(bary) - 1.0) > POINT_SUM_TOLERANCE:
                    raise PatternError(f"{what}: barycentric weights sum to {sum(bary)!r}, not 1 "
                                       f"(within {POINT_SUM_TOLERANCE:g})")
                key = _point_key(corners, bary)
            if key in pinned:
                raise PatternError(f"pattern.positional[{q}]: {entry!r} is pinned twice "
                                   f"(also pattern.positional[{pinned[key]}])")
            pinned[key] = q
        seen = set()
        for q, item in enumerate(self.contacts):
            if len(item) != 2:
                raise PatternError(f"pattern.contacts[{q}]: expected (vertex, axes), got {item!r}")
            v, axes = item
            if not isinstance(v, (int, np.integer)) or not 0 <= int(v) < n:
                raise PatternError(f"pattern.contacts[{q}]: vertex {v!r} is not in 0..{n - 1}")
            if (not isinstance(axes, str) or not axes or set(axes) - set("xyz")
                    or len(set(axes)) != len(axes)):
                raise PatternError(f"pattern.contacts[{q}]: axes {axes!r} must be distinct letters of 'xyz'")
            for a in axes:
                if (int(v), a) in seen:
                    raise PatternError(f"pattern.contacts[{q}]: vertex {v} axis {a} is constrained twice")
                seen.add((int(v), a))

        constrained = set(full) | set(children)
        for q, item in enumerate(self.limits):
            if len(item) != 6:
                raise PatternError(f"pattern.limits[{q}]: expected (child, parent, axis, swing, twist_min, twist_max)")
            c, p, axis, swing, lo, hi = item
            c, p = handle(c, f"limits[{q}] child"), handle(p, f"limits[{q}] parent")
            if c == p or c in constrained:
                raise PatternError(f"pattern.limits[{q}]: handle {c} must be free (not full, relative or its own parent)")
            d = np.asarray(axis, np.float64)
            if d.shape != (3,) or not np.isfinite(d).all() or abs(np.linalg.norm(d) - 1.0) > 1e-6:
                raise PatternError(f"pattern.limits[{q}]: axis {axis!r} is not a unit vector")
            if not (0.0 <= swing <= np.pi and -np.pi <= lo <= hi <= np.pi):
                raise PatternError(f"pattern.limits[{q}]: need 0 <= swing <= pi and -pi <= twist_min <= twist_max <= pi, "
                                   f"got {swing!r}, {lo!r}, {hi!r}")
        if self.limits and self.contacts:
            raise PatternError("pattern: joint limits together with contacts are not supported")

    def contact_axes(self) -> np.ndarray:
        """(len(contacts), 3) int32: 1 where contact q constrains column x, y or z."""
        out = np.zeros((len(self.contacts), 3), np.int32)
        for q, (_, axes) in enumerate(self.contacts):
            for a in axes:
                out[q, "xyz".index(a)] = 1
        return out

    def values(self) -> "Values":
        """Preallocated per-frame values for this pattern (identity rotations, zero targets)."""
        return Values(
            full=np.zeros((len(self.full), 4, 3), np.float32),
            relative=np.tile(np.eye(3, dtype=np.float32), (len(self.relative), 1, 1)),
            positional=np.zeros((len(self.positional), 3), np.float32),
            contact=np.zeros((len(self.contacts), 3), np.float32),
        )


def rest_positions(entries, V: np.ndarray) -> np.ndarray:
    """(k, 3) float64 rest positions of ``Pattern.positional`` entries on the rest mesh V (n, 3)."""
    corners, bary = positional_corners(entries)
    return np.einsum("kc,kcd->kd", bary, np.asarray(V, np.float64)[corners]) if len(entries) \
        else np.zeros((0, 3))


class PoseFill:
    """Writes a pattern's per-frame values from bone poses, for any pattern of a skeleton whose
    bone j is handle j: full blocks ``pose[j].T`` (4, 3) and relative rotations ``rot[child]``,
    in one native pass (puppet._kinematics.constraint_values: no per-bone loop, no allocation).

    pattern: the Pattern; its index arrays (int32) are made here. Positional and contact values
    are not touched (they are constant per rig: set them once, e.g. with :func:`rest_positions`).
    """

    def __init__(self, pattern: "Pattern"):
        self.full = np.array(pattern.full, np.int32)
        self.children = np.array([c for c, _, _ in pattern.relative], np.int32)

    def fill(self, values: "Values", rot: np.ndarray, pose: np.ndarray) -> None:
        """values: this pattern's Values (written); rot: (b, 3, 3) model-space joint rotations;
        pose: (b, 3, 4) bone affines [A_b | t_b] (see puppet.rig.skeleton), float64 C-contiguous
        (TypeError otherwise, never a copy); a bone index outside rot is a ValueError."""
        _kinematics.constraint_values(rot, pose, self.full, values.full, self.children, values.relative)


@dataclass
class Values:
    """Per-frame constraint values for a :class:`Pattern`; fill in place every frame.

    full:       (len(pattern.full), 4, 3) float32: the target T_j block (transform transposed).
    relative:   (len(pattern.relative), 3, 3) float32: the rotation R of each relative joint
                (child linear part = parent linear part @ R).
    positional: (len(pattern.positional), 3) float32: target positions of the pattern's vertices
                and surface points, model units.
    contact:    (len(pattern.contacts), 3) float32: target coordinates, model units; only the
                contact's axes are read.
    """

    full: np.ndarray
    relative: np.ndarray
    positional: np.ndarray
    contact: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
