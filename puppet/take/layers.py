"""Layered takes: a take of some joints recorded over a base (the layers below it), composed
into one time line by the one take-to-frames rule (``puppet.take.playback``).

A layer is an ordinary take (every servo's raw readings, as the bus gave them) with one more
MCAP metadata record, "puppet.layer" (crc32 as ``puppet.take.format.info_checksum``):

  base          the base take's path, relative to the layer's folder (or absolute)
  base_sha256   the base file's content hash: a base changed since is refused, named
  base_rig      the rig name the base was recorded on
  servos        the layer's servo ids (JSON list): the joints it holds
  punch_in      where the layer starts to hold them: seconds of layer time, or a marker's name
                ("" = the start); punch_out likewise ("" = the end)

Composition (``compose``), in the layer's time line (its readings' times, the playback rule's
gap cut applied): the base, itself composed when it is a layer, is sampled by ``Playback.sample``
at each reading's play time (the same start: play time 0 of both is their first reading; a base
that ends first holds its last frame, said); the layer's servos take the layer's ticks inside
[punch_in, punch_out] and the base's outside, blended at both seams over a window long enough
that the seam moves no faster than half the joints' median speed (the jump per frame stays
within the median frame-to-frame motion: no pop). The blend is in solve space: a servo's ticks
are linear in its joint angle, the solve's constraint, so blending ticks blends the constraints
the FAST solve is given (never the solved meshes). The top layer wins a servo two layers hold
(said once). Every layer keeps its raw readings: a layer is redone or dropped by playing its base
or recording over the base again.

Mute and solo (``LayerOptions``): a muted layer holds nothing (its base plays through it on its
time line); a solo layer is the only one that holds (every other layer of the stack muted).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet.take import format as fmt
from puppet.take.errors import TakeError

LAYER_METADATA = "puppet.layer"
MAX_DEPTH = 32
"""Most layers in one stack (a guard: hashes already make a cycle impossible)."""
BLEND_MIN_S = 0.2
"""Shortest blend at a seam, seconds."""
BLEND_MAX_S = 2.0
"""Longest blend at a seam, seconds (a seam between a still base and a still layer far apart)."""
BLEND_SPEED_FRACTION = 0.5
"""A seam's blend moves a joint at most this fraction of its median speed (on top of its motion)."""


@dataclass(frozen=True)
class LayerRef:
    """A layer's record: what it holds and what it was recorded over (see the module docstring).

    base: the base take's path as stored (relative to the layer's folder, or absolute).
    servos: the held servo ids. punch_in / punch_out: seconds (a number as text) or a marker's
    name; "" for the take's start / end.
    """

    base: str
    base_sha256: str
    base_rig: str
    servos: tuple[int, ...]
    punch_in: str = ""
    punch_out: str = ""

    def to_metadata(self) -> dict[str, str]:
        info = {"base": self.base, "base_sha256": self.base_sha256, "base_rig": self.base_rig,
                "servos": json.dumps([int(i) for i in self.servos]),
                "punch_in": self.punch_in, "punch_out": self.punch_out}
        info["crc32"] = fmt.info_checksum(info)
        return info

    @classmethod
    def from_metadata(cls, info: dict[str, str]) -> "LayerRef":
        """The record of a take; ValueError saying what is wrong."""
        from puppet.take.sync import check

        check(info)
        servos = tuple(int(i) for i in json.loads(info["servos"]))
        if not servos:
            raise ValueError("a layer holds no servos")
        return cls(base=info["base"], base_sha256=info["base_sha256"], base_rig=info["base_rig"],
                   servos=servos, punch_in=info.get("punch_in", ""),
                   punch_out=info.get("punch_out", ""))

    @classmethod
    def over(cls, base, layer_path, servos, *, rig_name: str, punch_in="",
             punch_out="") -> "LayerRef":
        """The record of a new layer at ``layer_path`` over the take ``base`` holding ``servos``
        (its path stored relative to the layer's folder when it is below it)."""
        from puppet.checksum import file_sha256

        base = Path(base)
        try:
            stored = str(base.resolve().relative_to(Path(layer_path).resolve().parent))
        except ValueError:
            stored = str(base.resolve())
        return cls(stored, file_sha256(base), rig_name, tuple(int(i) for i in servos),
                   str(punch_in), str(punch_out))


@dataclass(frozen=True)
class LayerOptions:
    """How a stack plays: ``mute`` layer paths that hold nothing, ``solo`` the one layer that
    holds (None: all), ``punch`` {layer path: (in, out)} overriding a layer's stored punch
    (seconds or marker names, "" for the start / end). Paths are compared resolved. ``strict``:
    a named layer that is not in the played take's stack is refused (play, export); a batch's
    options name layers of some of its takes (each named layer must exist)."""

    mute: frozenset = frozenset()
    solo: str | None = None
    punch: dict = field(default_factory=dict)
    strict: bool = True

    def _key(self, path) -> str:
        return str(Path(path).resolve())

    def holds(self, path) -> bool:
        key = self._key(path)
        if key in {self._key(p) for p in self.mute}:
            return False
        return self.solo is None or key == self._key(self.solo)

    @classmethod
    def from_flags(cls, mute=(), solo: str | None = None, punch=(),
                   strict: bool = True) -> "LayerOptions | None":
        """The options of ``--mute LAYER`` (repeatable), ``--solo LAYER`` and ``--punch
        LAYER=IN:OUT`` (repeatable; IN, OUT seconds or marker names, either empty for the
        start / end); None when none is given (the stack plays as recorded). TakeError naming
        the flag and its value when a punch is not LAYER=IN:OUT."""
        punches = {}
        for text in punch:
            layer, eq, span = str(text).rpartition("=")
            if not eq or not layer or span.count(":") != 1:
                raise TakeError("--punch", f"{text!r} is not LAYER=IN:OUT (seconds or marker "
                                           "names, e.g. layer.mcap=1.5:4 or layer.mcap=in:out)")
            t_in, t_out = span.split(":")
            punches[layer] = (t_in.strip(), t_out.strip())
        if not mute and solo is None and not punches:
            return None
        options = cls(frozenset(mute), solo, punches, strict)
        for flag, layer in options.named():
            if not Path(layer).is_file():
                raise TakeError(layer, f"{flag}: no such layer take")
        return options

    def named(self) -> list[tuple[str, str]]:
        """[(flag, layer path)] of every layer these options name."""
        return ([("--mute", str(p)) for p in sorted(map(str, self.mute))]
                + ([("--solo", str(self.solo))] if self.solo is not None else [])
                + [("--punch", str(p)) for p in self.punch])

    def as_dict(self) -> dict:
        """The options as JSON values, paths resolved (a batch manifest's settings)."""
        return {"mute": sorted(self._key(p) for p in self.mute),
                "solo": None if self.solo is None else self._key(self.solo),
                "punch": {self._key(p): list(map(str, v)) for p, v in sorted(self.punch.items())}}

    def punch_of(self, path, ref: LayerRef) -> tuple[str, str]:
        for p, punch in self.punch.items():
            if self._key(p) == self._key(path):
                return str(punch[0]), str(punch[1])
        return ref.punch_in, ref.punch_out


@dataclass
class Composed:
    """A stack's frames' input: t_ns (R,) int64, ticks (R, k) int32, ok (R, k) bool in the
    caller's ids order (the layer's time line); ``held`` {servo id: the layer path holding it};
    ``notes``: what the composition said (a base ending early, a servo two layers hold);
    ``seams``: [(play seconds, blend seconds)] of the top layer's punch in and out."""

    t_ns: np.ndarray
    ticks: np.ndarray
    ok: np.ndarray
    held: dict
    notes: list
    seams: list
    stack: list = field(default_factory=list)
    """The layer paths of the stack, bottom first (empty for a plain take)."""


def base_path(reader) -> Path:
    """Where the base of the layer open in ``reader`` is (its stored path, relative to the
    layer's folder)."""
    base = Path(reader.metadata.layer.base)
    return base if base.is_absolute() else Path(reader.path).parent / base


def open_base(reader):
    """The base of the layer open in ``reader`` as a TakeReader, checked: it exists, its
    content is the one recorded over (sha256), it was recorded on the layer's rig (TakeError
    naming both takes and both rigs), it is not a shot."""
    from puppet.checksum import file_sha256
    from puppet.take.reader import TakeReader

    ref = reader.metadata.layer
    path = base_path(reader)
    if not path.is_file():
        raise TakeError(reader.path, f"its base {path} is missing (a layer plays over its base)")
    if file_sha256(path) != ref.base_sha256:
        raise TakeError(reader.path, f"its base {path} changed since the layer was recorded "
                                     f"(sha256 {ref.base_sha256[:12]}… recorded)")
    base = TakeReader(path)
    check_same_rig(base.metadata, reader.metadata.rig_name, reader.metadata.ids,
                   layer=reader.path, base=path, models=reader.metadata.models)
    if base.keys() is not None and base.keys().keys:
        raise TakeError(reader.path, f"its base {path} is a shot (keys): a layer plays over takes")
    if len(base) == 0:
        raise TakeError(path, "the take holds no readings (the base of " f"{reader.path})")
    return base


def check_same_rig(base_metadata, rig_name: str, ids, *, layer, base, models=None) -> None:
    """TakeError naming both rigs unless the base (its TakeMetadata) was recorded on the rig
    ``rig_name`` with servos ``ids`` (of ``models``, {id: model}, where given)."""
    base_ids = sorted(int(i) for i in base_metadata.ids)
    ids = sorted(int(i) for i in ids)
    differ = models is not None and any(
        base_metadata.models.get(i) not in (None, models.get(i)) for i in ids)
    if base_metadata.rig_name != rig_name or base_ids != ids or differ:
        raise TakeError(layer, f"a layer on rig {rig_name!r} (servos {ids}) cannot go over "
                               f"{base}, recorded on rig {base_metadata.rig_name!r} (servos "
                               f"{base_ids}{', other models' if differ else ''}): record the "
                               "layer on the base's rig")


def _seconds(punch: str, marks, what: str, path, default: float) -> float:
    """A punch point as layer play seconds: a number, a marker's name or "" (default)."""
    if punch == "":
        return default
    try:
        value = float(punch)
    except ValueError:
        for t, name in marks:
            if name == punch:
                return t
        raise TakeError(path, f"{what} {punch!r} is neither seconds nor one of its markers "
                              f"{sorted({n for _, n in marks})}") from None
    if not math.isfinite(value) or value < 0:
        raise TakeError(path, f"{what} {punch!r} must be seconds >= 0")
    return value


def _median_speed(t_ns: np.ndarray, ticks: np.ndarray) -> np.ndarray:
    """(k,) median |d ticks / dt| per column, ticks per second (0 for a still column)."""
    if len(t_ns) < 2:
        return np.zeros(ticks.shape[1])
    dt = np.maximum(np.diff(t_ns), 1) * 1e-9
    return np.median(np.abs(np.diff(ticks.astype(float), axis=0)) / dt[:, None], axis=0)


def _blend_s(gap: np.ndarray, speed: np.ndarray) -> float:
    """Seconds a seam's blend lasts so that closing ``gap`` (k,) ticks moves each joint at most
    BLEND_SPEED_FRACTION of its median ``speed`` (k,) ticks/s; within [BLEND_MIN_S, BLEND_MAX_S]."""
    need = np.abs(gap) / np.maximum(BLEND_SPEED_FRACTION * speed, 1e-9)
    need = float(need.max()) if need.size else 0.0
    return min(max(need, BLEND_MIN_S), BLEND_MAX_S)


def compose(reader, ids, options: LayerOptions | None = None, _depth: int = 0) -> Composed:
    """The frames' input of the take open in ``reader`` for servos ``ids`` (a layer composed
    over its base, recursively; a plain take as recorded). See the module docstring."""
    from puppet.take.markers import read_markers
    from puppet.take.playback import Playback, play_times_ns, turns_of

    options = options or LayerOptions()
    ids = [int(i) for i in ids]
    t_ns, ticks, ok = reader.arrays(ids=ids)
    ref = reader.metadata.layer
    if ref is None:
        if _depth == 0:
            _check_named(reader, options, [])
        return Composed(t_ns, ticks, ok, {}, [], [])
    if _depth >= MAX_DEPTH:
        raise TakeError(reader.path, f"more than {MAX_DEPTH} layers in one stack")
    if len(t_ns) == 0:
        raise TakeError(reader.path, "the take holds no readings")
    base_reader = open_base(reader)
    below = compose(base_reader, ids, options, _depth + 1)
    notes = list(below.notes)
    base_ticks = below.ticks.astype(np.int64)
    if base_reader.metadata.calibration_text != reader.metadata.calibration_text:
        base_ticks += _zero_shift(base_reader, reader, ids)  # the base's ticks in the layer's zero
    turns = turns_of(reader.metadata.models, ids)
    base = Playback(below.t_ns, base_ticks, below.ok, np.asarray(ids), source=base_reader.path,
                    ticks_per_turn=turns)
    layer_play, _ = play_times_ns(t_ns)
    own = Playback(t_ns, ticks, ok, np.asarray(ids), source=reader.path, ticks_per_turn=turns)
    # the time line: every reading of the layer and of the base (within the layer), so that
    # each pass is sampled where it was read and interpolated only between its own readings
    play = np.union1d(layer_play, base.play_ns[base.play_ns <= layer_play[-1]])
    out = np.empty((len(play), len(ids)), np.int32)
    out_ok = np.empty((len(play), len(ids)), bool)
    ticks = np.empty_like(out)
    ok = np.empty_like(out_ok)
    for r, p in enumerate(play):  # both passes at each play time: the one rule
        base.sample(float(p), out[r], out_ok[r])
        own.sample(float(p), ticks[r], ok[r])
    t_ns = t_ns[0] + play
    duration_s = play[-1] * 1e-9
    if base.duration_s < duration_s:
        notes.append(f"{reader.path}: its base {base_reader.path} ends at "
                     f"{base.duration_s:.2f} s, before the layer ({duration_s:.2f} s): "
                     "the base holds its last frame")
    held = dict(below.held)
    seams: list = []
    if options.holds(reader.path):
        cols = [n for n, i in enumerate(ids) if i in set(ref.servos)]
        twice = [ids[n] for n in cols if ids[n] in held]
        if twice:
            names = sorted({str(held[i]) for i in twice})
            notes.append(f"servos {twice} are held by layer {reader.path} and by {', '.join(names)} "
                         "below it: the top layer wins")
        marks = [(float(p) * 1e-9, name)
                 for p, name in _mark_play(read_markers(reader.path), own.t_ns, own.play_ns)]
        p_in, p_out = options.punch_of(reader.path, ref)
        t_in = _seconds(p_in, marks, "punch in", reader.path, 0.0)
        t_out = _seconds(p_out, marks, "punch out", reader.path, duration_s)
        if t_out <= t_in:
            raise TakeError(reader.path, f"punch out ({t_out:.3f} s) is not after punch in "
                                         f"({t_in:.3f} s)")
        speed = np.maximum(_median_speed(own.t_ns, own.ticks[:, cols]),  # each pass's own
                           _median_speed(base.t_ns, base.ticks[:, cols]))
        weight = _weights(play * 1e-9, t_in, t_out, ticks[:, cols], out[:, cols], speed, seams)
        blend = out[:, cols] + weight[:, None] * (ticks[:, cols].astype(float) - out[:, cols])
        out[:, cols] = np.rint(blend).astype(np.int32)
        inside = weight > 0
        out_ok[np.ix_(inside, cols)] = ok[np.ix_(inside, cols)] & (
            out_ok[np.ix_(inside, cols)] | (weight[inside] >= 1)[:, None])
        for n in cols:
            held[ids[n]] = reader.path
    stack = [*below.stack, reader.path]
    if _depth == 0:
        _check_named(reader, options, stack)
    return Composed(t_ns, out, out_ok, held, notes, seams, stack)


def _check_named(reader, options: LayerOptions, stack) -> None:
    """TakeError naming the flag and the layer when ``options`` name a layer that is not in
    the stack of the take open in ``reader`` (a typo must not play the stack as recorded)."""
    if not options.strict:
        return
    known = {str(Path(p).resolve()) for p in stack}
    for flag, layer in options.named():
        if str(Path(layer).resolve()) not in known:
            have = ", ".join(str(p) for p in stack) or "none: it is not a layered take"
            raise TakeError(reader.path, f"{flag} {layer}: not a layer of this take's stack "
                                         f"(its layers: {have})")


def _mark_play(marks, t_ns, play):
    """[(play ns, name)] of markers at recorded times."""
    out = []
    for t, name in marks:
        i = int(np.clip(np.searchsorted(t_ns, t, side="right") - 1, 0, len(t_ns) - 1))
        out.append((int(play[i] + max(0, min(t - t_ns[i], (play[min(i + 1, len(play) - 1)] - play[i])))), name))
    return out


def _weights(play_s, t_in, t_out, layer, base, speed, seams) -> np.ndarray:
    """(R,) the layer's weight at each reading: 0 outside [t_in, t_out], 1 inside, linear over
    each seam's blend (its length from the gap the seam closes and the joints' median
    ``speed``, (l,) ticks/s)."""
    w = ((play_s >= t_in) & (play_s <= t_out)).astype(float)
    end = play_s[-1]
    if t_in > 0:
        r = int(np.searchsorted(play_s, t_in))
        r = min(r, len(play_s) - 1)
        b = _blend_s(layer[r].astype(float) - base[r], speed)
        seams.append((t_in, b))
        ramp = (play_s - t_in) / b
        inside = (play_s >= t_in) & (play_s < t_in + b)
        w[inside] = np.minimum(w[inside], ramp[inside])
    if t_out < end:
        r = min(int(np.searchsorted(play_s, t_out)), len(play_s) - 1)
        b = _blend_s(layer[r].astype(float) - base[r], speed)
        seams.append((t_out, b))
        ramp = (t_out - play_s) / b
        inside = (play_s > t_out - b) & (play_s <= t_out)
        w[inside] = np.minimum(w[inside], ramp[inside])
    return np.clip(w, 0.0, 1.0)


def _zero_shift(base_reader, reader, ids) -> np.ndarray:
    """(k,) ticks to add to the base's to read them in the layer's calibration (zero ticks of
    each; a recalibration between passes)."""
    from puppet.rig.calibration import Calibration  # only for stacks recalibrated between passes

    was = Calibration.from_record(base_reader.metadata.calibration_text, base_reader.path).zero_ticks
    now = Calibration.from_record(reader.metadata.calibration_text, reader.path).zero_ticks
    return np.array([now.get(i, 0) - was.get(i, 0) if i in now and i in was else 0 for i in ids],
                    np.int64)


def layer_notes(reader) -> list[str]:
    """What playing the take open in ``reader`` says about its layers (nothing for a plain
    take); the stack checked (TakeError as ``compose``)."""
    if reader.metadata.layer is None:
        return []
    return compose(reader, [int(i) for i in reader.metadata.ids]).notes
