"""Guided calibration: find each [[servo]] block's bus id, sign and zero ticks by asking the
user to move its joint, and write them back into the rig file (comments and layout kept).

Steps (``GuidedCalibration.run``):
1. the puppet is held in the rig's rest pose: every servo on the bus is read (median of a few
   clean readings): these are the zero ticks;
2. for each [[servo]] block in file order: "move <joint> in its positive direction" (or its
   negative one when the block's ``limits_deg`` leave the joint less room that way: the side
   with room, ``turn_direction``); the one servo that leaves its zero by more than
   the threshold and is held there is the block's servo, and the side it went to is its
   sign (``angle = sign · (ticks − zero) ...``, so a positive joint turn reads positive);
3. "back to the rest pose": every servo returns within half the threshold of its zero;
4. ``id``, ``sign`` and ``zero_ticks`` (and ``model``, from the bus) are written into each block
   with tomlkit, which keeps the user's comments and layout; the result is checked as a rig
   file before it replaces the old one (atomically).

A servo it is unsure of is never assigned: the joint is asked again, with the reason, when
- two servos moved past the threshold at once;
- a servo moved less than the threshold and came back (a move too small to count);
- the servo that moved was found for an earlier block, or turned farther than the joint's own
  ``limits_deg`` allow that way (another joint's servo), or is the ``id`` another block of the
  file names (accepted only when the same servo is moved again on the next ask: the file's id
  may be a placeholder);
and after ``TRIES`` unsure asks it stops with an error. Nothing is written until every block
is resolved: an error or Ctrl-C part way leaves the rig file as it was.

The threshold is an angle: degrees of joint turn (``threshold_deg``, default THRESHOLD_DEG),
the same on every model. Each servo's ticks for it come from the one conversion,
``puppet.servo_models.ServoUnits`` (the servo's model's ticks per turn, the block's gear): 13°
is 148 ticks on an X-series or MX servo (4096 per turn) and 44 on an AX-12A (1024 positions over
300°). The room check (a joint whose limits leave less than the threshold / ROOM_SHARE on the
asked side is refused before anything is read) uses the same angle.

The bus is not imported here: ``run`` takes a ``read()`` callable returning a reading with
``ids`` (k,), ``ticks`` (k,) int32 and ``ok`` (k,) bool (``puppet.bus.Reading``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from puppet import limits
from puppet.rig.errors import RigError
from puppet.servo_models import MODELS, TICKS_PER_TURN, ServoUnits

#: Degrees of joint turn a move must reach to count, by default (``--threshold``).
THRESHOLD_DEG = limits.THRESHOLD_DEG_DEFAULT
#: Ticks of steady deviation that are sensor noise on any model, never a move too small to count.
NOISE_TICKS = 3
#: Readings in a row that must agree on the moved servo (one corrupt reading is not a move).
CONFIRM = 3
#: Readings in a row in which the move grows by no more than threshold/8: the joint is held,
#: and its extent is measured.
HELD = 8
#: Asks per block before giving up (a bus where every servo moves never settles).
TRIES = 5
#: Pause between readings while waiting for the user, s (a person is slow; the bus need not spin).
POLL_S = 0.01
#: Degrees of joint turn a guided move aims for. A joint is asked to move positive unless its
#: upper limit is nearer than this and its lower side has more room (``turn_direction``).
#: hw_sim's ``OneAtATime`` (the simulated person) follows the same rule; a test checks they agree.
TURN_DEG = 30.0
#: A move must fit this share of the room a joint's limits leave on the asked side.
ROOM_SHARE = 0.8
#: A servo that turned farther than the joint's room × ROOM_SLACK + SLACK_DEG is another joint's.
ROOM_SLACK, SLACK_DEG = 1.1, 5.0
NAMED_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def turn_direction(limits_deg) -> int:
    """+1 or -1: the side of the rest pose (0°) a joint with ``limits_deg`` (low, high) is asked
    to turn toward: positive unless the upper limit is below TURN_DEG and the lower side has
    more room (a knee with limits [-90, 10] is asked to bend negative)."""
    low, high = (float(x) for x in limits_deg)
    return 1 if high >= TURN_DEG or high >= -low else -1


@dataclass
class Step:
    """One [[servo]] block to calibrate.

    index: position in the file's [[servo]] array; joint: bone name; axis_text: the axis as
    written; axis: (3,) unit axis in the bone's rest frame; hint: words for a positive turn;
    hint_negative: words for a negative one; limits_deg: (low, high) joint limits, degrees;
    gear: servo turns per joint turn; file_id: the ``id`` the block has now (maybe a
    placeholder), or None.
    """

    index: int
    joint: str
    axis_text: str
    axis: np.ndarray
    hint: str = ""
    hint_negative: str = ""
    limits_deg: tuple[float, float] = (-180.0, 180.0)
    gear: float = 1.0
    file_id: int | None = None

    @property
    def direction(self) -> int:
        """+1 / -1: the side this joint is asked to move toward (``turn_direction``)."""
        return turn_direction(self.limits_deg)

    @property
    def room_deg(self) -> float:
        """Degrees of joint turn the limits leave from the rest pose on the asked side."""
        low, high = self.limits_deg
        return max(high if self.direction > 0 else -low, 0.0)


@dataclass
class Found:
    """What a step found: the servo's bus id, its sign, and its zero ticks."""

    step: Step
    id: int
    sign: int
    zero_ticks: int


class _Unsure(Exception):
    """One ask that found no servo for sure: ``reason`` in words; ``claimed``: the servo another
    block's id names, when that was the only doubt (moving it again takes it)."""

    def __init__(self, reason: str, claimed: int | None = None) -> None:
        super().__init__(reason)
        self.reason, self.claimed = reason, claimed


def _parse_axis(value, where: str, path: Path) -> tuple[str, np.ndarray]:
    if isinstance(value, str) and value.strip().lower().lstrip("+-") in NAMED_AXES:
        key = value.strip().lower()
        axis = np.array(NAMED_AXES[key.lstrip("+-")]) * (-1.0 if key.startswith("-") else 1.0)
        return key, axis
    try:
        axis = np.array([float(x) for x in value], np.float64)
    except (TypeError, ValueError):
        axis = np.zeros(0)
    if axis.shape != (3,) or np.linalg.norm(axis) < 1e-9:
        raise RigError(f"axis must be x, y, z (optionally signed) or three numbers, got {value!r}",
                       path=path, field=f"{where} axis")
    return str(list(value)), axis / np.linalg.norm(axis)


def _parse_range(block, where: str, path: Path) -> tuple[tuple[float, float], float]:
    """(limits_deg (low, high), gear) of a block, checked as the rig file checks them."""
    from puppet.rig.rig_file import GEAR, LIMIT_DEG

    value = block.get("limits_deg", [-180.0, 180.0])
    if (not isinstance(value, list) or len(value) != 2 or not all(map(LIMIT_DEG.holds, value))
            or not value[0] < value[1]):
        raise RigError(f"limits_deg must be [low, high], low < high, each {LIMIT_DEG}, got {value!r}",
                       path=path, field=f"{where} limits_deg")
    gear = block.get("gear", 1.0)
    if not GEAR.holds(gear):
        raise RigError(f"gear {GEAR.problem(gear)}", path=path, field=f"{where} gear")
    return (float(value[0]), float(value[1])), float(gear)


def _character_skeleton(doc: dict, path: Path):
    """The character's skeleton (for names and words), or None for formats not read here."""
    mesh = doc.get("mesh")
    if not isinstance(mesh, str):
        raise RigError("missing (the character's mesh file)", path=path, field="mesh")
    mesh_path = (path.parent / mesh).resolve()
    suffix = mesh_path.suffix.lower()
    if suffix in (".glb", ".gltf"):
        from puppet.rig.gltf import read_gltf

        skin = doc.get("skin")
        return read_gltf(mesh_path, skin=int(skin) if isinstance(skin, int) else None).skeleton
    if suffix == ".npz":
        from puppet.rig.load import read_character_npz

        return read_character_npz(mesh_path)[3]
    return None


def _units(ids, models: dict[int, str], gear: float) -> ServoUnits:
    """Units of the servos ``ids`` as one joint of ``gear``: each its model's ticks per turn
    (X-series when its model is unknown); ``ticks_per_joint_degree`` (k,) is what a guided
    move's angles convert by."""
    k = len(ids)
    turns = [MODELS[models[i]].ticks_per_turn if models.get(i) in MODELS else TICKS_PER_TURN
             for i in ids]
    return ServoUnits(np.ones(k), np.full(k, float(gear)), np.zeros(k, np.int64),
                      ticks_per_turn=turns if k else TICKS_PER_TURN)


class GuidedCalibration:
    """The steps of one rig file, and the write-back.

    path: the rig file (TOML). Raises RigError naming the file and the block at fault when a
    block has no joint, an unknown joint, a bad axis, limits or gear, or when the file has no
    [[servo]] block.
    """

    def __init__(self, path) -> None:
        import tomlkit
        from tomlkit.exceptions import TOMLKitError

        self.path = Path(path)
        self.models: dict[int, str] = {}
        self.calibration_file: Path | None = None   # also updated by write(), when the rig names one
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise RigError("rig file not found", path=self.path) from None
        except (OSError, UnicodeDecodeError) as err:
            raise RigError(f"cannot read rig file: {err}", path=self.path) from err
        try:
            self.doc = tomlkit.parse(text)
        except TOMLKitError as err:
            raise RigError(f"not valid TOML: {err}", path=self.path) from err
        blocks = self.doc.get("servo")
        if not blocks:
            raise RigError("no [[servo]] blocks: uncomment one for each servo in the puppet (joint "
                           "and axis set; id, sign and zero_ticks are found here)", path=self.path,
                           field="servo")
        skeleton = _character_skeleton(self.doc, self.path)
        self.steps: list[Step] = []
        for i, block in enumerate(blocks):
            where = f"servo #{i + 1}"
            joint = block.get("joint")
            if not isinstance(joint, str) or not joint:
                raise RigError(f"joint must be a bone name, got {joint!r}", path=self.path,
                               field=f"{where} joint")
            fixed = self.doc.get("fixed", [])
            if isinstance(fixed, list) and joint in fixed:  # before any asking: the rig's rule
                raise RigError(f"servo on joint {joint!r}, which 'fixed' holds rigidly: a fixed "
                               "bone has no joint to read; remove the bone from 'fixed' or the "
                               "servo", path=self.path, field=f"{where} joint")
            axis_text, axis = _parse_axis(block.get("axis", "x"), where, self.path)
            limits_deg, gear = _parse_range(block, where, self.path)
            file_id = block.get("id")
            file_id = int(file_id) if isinstance(file_id, int) and not isinstance(file_id, bool) else None
            hint = hint_negative = ""
            if skeleton is not None:
                if joint not in skeleton.names:
                    raise RigError(f"unknown joint {joint!r}; bones are {list(skeleton.names)}",
                                   path=self.path, field=f"{where} joint")
                from puppet.rig.directions import turn_words

                b = skeleton.index(joint)
                hint = turn_words(skeleton.frames[b], skeleton.heads[b], skeleton.tails[b], axis)
                hint_negative = turn_words(skeleton.frames[b], skeleton.heads[b], skeleton.tails[b], -axis)
            self.steps.append(Step(i, str(joint), axis_text, axis, hint, hint_negative, limits_deg,
                                   gear, file_id))

    def _where(self, step: Step) -> str:
        return f"servo #{step.index + 1} ({step.joint})"

    # ---- the session -------------------------------------------------------------------------
    def run(self, read: Callable, zero_reading, *, say: Callable[[str], None],
            models: dict[int, str] | None = None, threshold_deg: float = THRESHOLD_DEG,
            timeout_s: float = 60.0) -> list[Found]:
        """Ask for every step and detect its servo; nothing is assigned unless sure.

        read: () -> reading (ids, ticks, ok); zero_reading: a clean reading at the rest pose (its
        ids are the servos on the bus); say: prints a prompt (stderr in the command line);
        models: {id: model name} found on the bus, written into the blocks and giving each
        servo's ticks per turn (X-series when absent); threshold_deg: degrees of joint turn a
        move must reach to count; timeout_s: per ask.
        Raises RigError naming the joint whose limits leave no room for a move of
        ``threshold_deg`` (before any reading), or whose servo did not move or return in time,
        or that got no sure move in TRIES asks.
        """
        for name, value, bound in (("threshold_deg", threshold_deg, limits.THRESHOLD_DEG),
                                   ("timeout_s", timeout_s, limits.TIMEOUT_S)):
            if not bound.holds(value):  # 0 would take a still servo for a moved one
                raise RigError(bound.problem(value), path=self.path, field=name)
        threshold_deg = float(threshold_deg)
        for step in self.steps:  # a joint that cannot turn far enough is told before anything is read
            if step.room_deg < threshold_deg / ROOM_SHARE:
                raise RigError(
                    f"{list(step.limits_deg)} leave the joint at most {step.room_deg:g}° of turn from "
                    f"the rest pose on the side it is asked to move toward, too little for a clear "
                    f"move: one counts from {threshold_deg:g}° of joint turn; widen the limits or "
                    f"lower --threshold", path=self.path,
                    field=f"servo #{step.index + 1} ({step.joint}) limits_deg")
        ids = [int(i) for i in zero_reading.ids]
        zero = np.asarray(zero_reading.ticks, np.int64).copy()
        if len(ids) < len(self.steps):
            raise RigError(f"{len(self.steps)} [[servo]] blocks but only {len(ids)} servos answer on "
                           f"the bus ({ids})", path=self.path, field="servo")
        self.models = dict(models or {})
        assigned: dict[int, str] = {}
        found: list[Found] = []
        settled = np.zeros(len(ids), np.int64)   # |ticks - zero| when the last wait for rest ended
        for k, step in enumerate(self.steps):
            units = _units(ids, self.models, step.gear)
            threshold = threshold_deg * units.ticks_per_joint_degree   # (k,) ticks, per servo
            claims = {s.file_id: s.joint for s in self.steps[k + 1:] if s.file_id is not None
                      and s.file_id != step.file_id}
            side = "positive" if step.direction > 0 else "negative"
            hint = step.hint if step.direction > 0 else step.hint_negative
            hint = f": {hint}" if hint else ""
            room = "" if step.direction > 0 else (f"; its limits {list(step.limits_deg)} leave more room "
                                                  "that way")
            insisted = None
            for attempt in range(1, TRIES + 1):
                again = "" if attempt == 1 else f" (ask {attempt} of {TRIES})"
                say(f"[{k + 1}/{len(self.steps)}] move {step.joint!r} in its {side} direction "
                    f"(about {step.axis_text}{hint}{room}) and hold it{again}")
                try:
                    servo, ticks_side = self._detect(read, ids, zero, settled, step, assigned, claims,
                                                     insisted, units, threshold_deg, timeout_s)
                    break
                except _Unsure as unsure:
                    if attempt == TRIES:
                        raise RigError(f"no sure move in {TRIES} asks (the last: {unsure.reason}); "
                                       "nothing was written", path=self.path,
                                       field=self._where(step)) from None
                    insisted = unsure.claimed
                    say(f"  not sure, asking again: {unsure.reason}; back to the rest pose first")
                    settled = self._wait_rest(read, ids, zero, step, threshold, timeout_s)
            sign = step.direction * ticks_side
            assigned[servo] = step.joint
            found.append(Found(step, servo, sign, int(zero[ids.index(servo)])))
            say(f"  {step.joint!r}: servo {servo}, sign {sign:+d}; now back to the rest pose")
            settled = self._wait_rest(read, ids, zero, step, threshold, timeout_s)
        return found

    def _detect(self, read, ids, zero, settled, step, assigned, claims, insisted, units,
                threshold_deg, timeout_s) -> tuple[int, int]:
        """(bus id, +1/-1 side its ticks went) of the one servo that left its zero by more than
        ``threshold_deg`` of joint turn (its ticks by ``units``; the same side in CONFIRM
        readings in a row) and was held there for HELD readings; _Unsure with the reason when
        that servo cannot be this step's.

        settled: (k,) |ticks − zero| when the puppet was last found at rest, before this ask (a
        joint still easing back from there is not a new move)."""
        deadline = time.monotonic() + timeout_s
        threshold = threshold_deg * units.ticks_per_joint_degree   # (k,) ticks, per servo
        notice = np.maximum(threshold / 3, NOISE_TICKS)   # a move, though too small to count
        rows = np.zeros((CONFIRM, len(ids)), np.int64)  # per servo: its last good deviations, ticks
        good = np.zeros(len(ids), np.int64)    # per servo: good readings so far (a servo whose
        #                                        reply was lost keeps its last good ones)
        peak = np.zeros(len(ids), np.int64)    # per servo: the largest steady deviation, ticks
        moved, anchor, still = None, 0, 0      # the candidate's index, its extent, readings held
        while time.monotonic() < deadline:
            reading = read()
            ok = np.asarray(reading.ok, bool)
            rows[:, ok] = np.roll(rows[:, ok], -1, axis=0)
            rows[-1, ok] = np.asarray(reading.ticks, np.int64)[ok] - zero[ok]
            good[ok] += 1
            if good.max() >= CONFIRM:
                same_side = (np.sign(rows) == np.sign(rows[-1])).all(axis=0) & (good >= CONFIRM)
                steady = np.where(same_side, np.abs(rows).min(axis=0), 0)   # reached in every one
                peak = np.maximum(peak, steady)
                over = np.flatnonzero(steady >= threshold)
                if len(over) > 1:
                    names = " and ".join(str(ids[i]) for i in over)
                    raise _Unsure(f"servos {names} both moved more than {threshold_deg:g}°: move only "
                                  f"{step.joint!r}")
                if moved is None and len(over) == 1:
                    moved, still = int(over[0]), 0
                    anchor, side = int(steady[moved]), int(np.sign(rows[-1][moved]))
                elif moved is not None:
                    if steady[moved] > anchor + max(threshold[moved] / 8, 1):
                        anchor, still = int(steady[moved]), 0
                    else:
                        still += 1
                    if still >= HELD:
                        self._check(ids[moved], float(units.joint_degrees(peak)[moved]), step,
                                    assigned, claims, insisted)
                        return ids[moved], side
                small = ((peak - settled >= notice) & (peak < threshold)
                         & (steady <= np.minimum(threshold / 2, peak / 2)))
                if moved is None and small.any():
                    i = int(np.argmax(np.where(small, peak, -1)))
                    raise _Unsure(f"servo {ids[i]} moved only {units.joint_degrees(peak)[i]:.1f}° "
                                  f"({int(peak[i])} ticks) and came back; a move counts from "
                                  f"{threshold_deg:g}° ({threshold[i]:.0f} ticks on it): move "
                                  f"{step.joint!r} farther")
            time.sleep(POLL_S)
        largest = int(np.argmax(peak))
        seen = (f"; the largest move: servo {ids[largest]}, {units.joint_degrees(peak)[largest]:.1f}° "
                f"({int(peak[largest])} ticks)" if peak[largest] > 0 else "")
        raise RigError(f"no servo moved more than {threshold_deg:g}° of joint turn from its zero within "
                       f"{timeout_s:g} s (servos on the bus: {ids}{seen})", path=self.path,
                       field=self._where(step))

    def _check(self, servo, turned, step, assigned, claims, insisted) -> None:
        """_Unsure unless ``servo``, which moved ``turned`` degrees of joint turn, can be
        ``step``'s servo."""
        if servo in assigned:
            raise _Unsure(f"servo {servo} moved, but it is {assigned[servo]!r}'s (found before): move "
                          f"{step.joint!r}, with {assigned[servo]!r} at rest")
        if turned > step.room_deg * ROOM_SLACK + SLACK_DEG:
            raise _Unsure(f"servo {servo} turned {turned:.0f}°, but {step.joint!r} turns at most "
                          f"{step.room_deg:g}° that way (limits_deg {list(step.limits_deg)}): it is "
                          f"another joint's servo; move {step.joint!r}")
        if servo in claims and servo != insisted:
            raise _Unsure(f"servo {servo} is the id the rig file gives {claims[servo]!r}: move "
                          f"{step.joint!r}, or move servo {servo} again if that id is wrong",
                          claimed=servo)

    def _wait_rest(self, read, ids, zero, step, threshold, timeout_s) -> np.ndarray:
        """Wait until every servo is within half its ``threshold`` ((k,) ticks) of its zero;
        (k,) |ticks − zero| then."""
        deadline = time.monotonic() + timeout_s
        near = threshold / 2
        away = {}
        while time.monotonic() < deadline:
            reading = read()
            dev = np.abs(np.asarray(reading.ticks, np.int64) - zero)
            if reading.ok.all() and (dev <= near).all():
                return dev
            away = {ids[k]: int(dev[k]) for k in np.flatnonzero(dev > near)}
            time.sleep(POLL_S)
        where = ", ".join(f"servo {i} {d} ticks" for i, d in away.items()) or "a servo not answering"
        raise RigError(f"the puppet did not return to the rest pose within {timeout_s:g} s after moving "
                       f"{step.joint!r} (away from rest: {where})", path=self.path,
                       field=self._where(step))

    # ---- write-back ----------------------------------------------------------------------------
    def check_out(self, out=None, *, force: bool = False) -> Path:
        """The rig file to write (``out``, default: the rig file itself), checked by
        ``puppet.atomic``'s rule: another path may be none of the rig's files (character,
        buffers, calibration), nor a device, nor another kind of file without ``force``."""
        from puppet.atomic import check_output

        if out is None:
            return check_output(self.path, kind="rig file", force=True, what="rig file")
        return check_output(out, kind="rig file", inputs=self._inputs(), force=force,
                            what="rig file")

    def _inputs(self) -> list[Path]:
        from puppet.rig.rig_file import input_files

        try:
            return input_files(self.path)
        except RigError:  # unreadable as a rig: then only the file itself is known
            return [self.path]

    def write(self, found: list[Found], out=None, *, force: bool = False) -> Path:
        """Write id, sign, zero_ticks (and the bus's model) into the blocks; comments kept.

        out: another rig file to write (default: the rig file itself). The new text is checked as
        a rig file before it replaces anything; written atomically.
        """
        from puppet.atomic import atomic_output
        from puppet.rig.rig_file import read_rig_file

        blocks = self.doc["servo"]
        for f in found:
            block = blocks[f.step.index]
            _set(block, "id", f.id)
            model = self.models.get(f.id)
            if model is not None:
                _set(block, "model", model)
            _set(block, "sign", f.sign)
            _set(block, "zero_ticks", f.zero_ticks)
        import tomlkit

        text = tomlkit.dumps(self.doc)
        target = Path(out) if out is not None else self.path
        if target.resolve() != self.path.resolve() and target.parent.resolve() != self.path.parent.resolve():
            raise RigError("the calibrated rig file must sit next to the original (its character "
                           "file is named relative to it)", path=target)
        rule = (dict(force=True) if out is None
                else dict(inputs=self._inputs(), force=force))
        with atomic_output(target, kind="rig file", what="rig file", **rule) as temporary:
            temporary.write_text(text, encoding="utf-8")
            try:
                spec = read_rig_file(temporary)
            except RigError as err:
                raise RigError(f"the calibrated rig would not load, nothing written: {err}",
                               path=target) from err
        self.calibration_file = None
        if spec.calibration is not None and spec.calibration.exists():
            # A calibration file overrides the rig's zero_ticks: keep it in step.
            from puppet.rig.calibration import Calibration

            calibration = Calibration.load(spec.calibration)
            calibration.zero_ticks.update({f.id: f.zero_ticks for f in found})
            self.calibration_file = calibration.save(spec.calibration)
        return target


def _set(table, key: str, value) -> None:
    """Set ``table[key]`` keeping the comment after the old value, if any."""
    import tomlkit

    if key in table:
        old = table.item(key)
        new = tomlkit.item(value)
        new.trivia.comment = old.trivia.comment
        new.trivia.comment_ws = old.trivia.comment_ws
        table[key] = new
    else:
        table[key] = value
