"""Guided calibration: find each [[servo]] block's bus id, sign and zero ticks by asking the
user to move its joint, and write them back into the rig file (comments and layout kept).

Steps (``GuidedCalibration.run``):
1. the puppet is held in the rig's rest pose: every servo on the bus is read (median of a few
   clean readings): these are the zero ticks;
2. for each [[servo]] block in file order: "move <joint> in its positive direction"; the first
   servo (not yet assigned) whose ticks leave its zero by more than ``threshold_ticks`` is the
   block's servo, and the side it went to is its sign (``angle = sign · (ticks − zero) ...``,
   so a positive joint turn reads positive);
3. "back to the rest pose": every servo returns within ``threshold_ticks / 2`` of its zero;
4. ``id``, ``sign`` and ``zero_ticks`` (and ``model``, from the bus) are written into each block
   with tomlkit, which keeps the user's comments and layout; the result is checked as a rig
   file before it replaces the old one (atomically).

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

#: About 13° of servo shaft: a deliberate move, far above sensor noise (a few ticks).
THRESHOLD_TICKS = 150
#: Readings in a row that must agree on the moved servo (one corrupt reading is not a move).
CONFIRM = 3
#: Pause between readings while waiting for the user, s (a person is slow; the bus need not spin).
POLL_S = 0.01
NAMED_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


@dataclass
class Step:
    """One [[servo]] block to calibrate.

    index: position in the file's [[servo]] array; joint: bone name; axis_text: the axis as
    written; axis: (3,) unit axis in the bone's rest frame; hint: words for a positive turn.
    """

    index: int
    joint: str
    axis_text: str
    axis: np.ndarray
    hint: str = ""


@dataclass
class Found:
    """What a step found: the servo's bus id, its sign, and its zero ticks."""

    step: Step
    id: int
    sign: int
    zero_ticks: int


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


class GuidedCalibration:
    """The steps of one rig file, and the write-back.

    path: the rig file (TOML). Raises RigError naming the file and the block at fault when a
    block has no joint, an unknown joint or a bad axis, or when the file has no [[servo]] block.
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
            axis_text, axis = _parse_axis(block.get("axis", "x"), where, self.path)
            hint = ""
            if skeleton is not None:
                if joint not in skeleton.names:
                    raise RigError(f"unknown joint {joint!r}; bones are {list(skeleton.names)}",
                                   path=self.path, field=f"{where} joint")
                from puppet.rig.directions import turn_words

                b = skeleton.index(joint)
                hint = turn_words(skeleton.frames[b], skeleton.heads[b], skeleton.tails[b], axis)
            self.steps.append(Step(i, str(joint), axis_text, axis, hint))

    # ---- the session -------------------------------------------------------------------------
    def run(self, read: Callable, zero_reading, *, say: Callable[[str], None],
            models: dict[int, str] | None = None, threshold_ticks: int = THRESHOLD_TICKS,
            timeout_s: float = 60.0) -> list[Found]:
        """Ask for every step and detect its servo.

        read: () -> reading (ids, ticks, ok); zero_reading: a clean reading at the rest pose (its
        ids are the servos on the bus); say: prints a prompt (stderr in the command line);
        models: {id: model name} found on the bus, written into the blocks; timeout_s: per joint.
        Raises RigError naming the joint whose servo did not move or return in time.
        """
        for name, value, bound in (("threshold_ticks", threshold_ticks, limits.THRESHOLD_TICKS),
                                   ("timeout_s", timeout_s, limits.TIMEOUT_S)):
            if not bound.holds(value):  # 0 would take a still servo for a moved one
                raise RigError(bound.problem(value), path=self.path, field=name)
        ids = [int(i) for i in zero_reading.ids]
        zero = np.asarray(zero_reading.ticks, np.int64).copy()
        if len(ids) < len(self.steps):
            raise RigError(f"{len(self.steps)} [[servo]] blocks but only {len(ids)} servos answer on "
                           f"the bus ({ids})", path=self.path, field="servo")
        self.models = dict(models or {})
        assigned: dict[int, str] = {}
        found: list[Found] = []
        for k, step in enumerate(self.steps):
            hint = f": {step.hint}" if step.hint else ""
            say(f"[{k + 1}/{len(self.steps)}] move {step.joint!r} in its positive direction "
                f"(about {step.axis_text}{hint}) and hold it")
            servo, sign = self._detect(read, ids, zero, assigned, step, say, threshold_ticks, timeout_s)
            assigned[servo] = step.joint
            found.append(Found(step, servo, sign, int(zero[ids.index(servo)])))
            say(f"  {step.joint!r}: servo {servo}, sign {sign:+d}; now back to the rest pose")
            self._wait_rest(read, ids, zero, step, threshold_ticks, timeout_s)
        return found

    def _detect(self, read, ids, zero, assigned, step, say, threshold, timeout_s) -> tuple[int, int]:
        """The servo that left its zero by more than ``threshold`` ticks in CONFIRM readings in a
        row (the same servo, the same side), and that side."""
        deadline = time.monotonic() + timeout_s
        warned: set[int] = set()
        candidate, run = None, 0
        while time.monotonic() < deadline:
            reading = read()
            dev = np.where(reading.ok, np.asarray(reading.ticks, np.int64) - zero, 0)
            k = int(np.argmax(np.abs(dev)))
            seen = (ids[k], 1 if dev[k] > 0 else -1) if abs(int(dev[k])) >= threshold else None
            candidate, run = (seen, run + 1) if seen is not None and seen == candidate else (seen, 1)
            if seen is not None and seen[0] in assigned:
                if seen[0] not in warned:
                    say(f"  servo {seen[0]} moved, but it belongs to {assigned[seen[0]]!r}; move "
                        f"{step.joint!r} (put {assigned[seen[0]]!r} back at rest)")
                    warned.add(seen[0])
            elif seen is not None and run >= CONFIRM:
                return seen
            time.sleep(POLL_S)
        raise RigError(f"no servo moved more than {threshold} ticks from its zero within {timeout_s:g} s "
                       f"(servos on the bus: {ids})", path=self.path, field=f"servo #{step.index + 1} "
                       f"({step.joint})")

    def _wait_rest(self, read, ids, zero, step, threshold, timeout_s) -> None:
        deadline = time.monotonic() + timeout_s
        away = {}
        while time.monotonic() < deadline:
            reading = read()
            dev = np.abs(np.asarray(reading.ticks, np.int64) - zero)
            if reading.ok.all() and dev.max() <= threshold // 2:
                return
            away = {ids[k]: int(dev[k]) for k in np.flatnonzero(dev > threshold // 2)}
            time.sleep(POLL_S)
        where = ", ".join(f"servo {i} {d} ticks" for i, d in away.items()) or "a servo not answering"
        raise RigError(f"the puppet did not return to the rest pose within {timeout_s:g} s after moving "
                       f"{step.joint!r} (away from rest: {where})", path=self.path,
                       field=f"servo #{step.index + 1} ({step.joint})")

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
