"""Calibration: host-side zero ticks per servo id (TOML or JSON), never written to a servo.

File layout (TOML; JSON has the same shape)::

    # puppet calibration: encoder ticks at the rig's rest pose
    [zero_ticks]
    1 = 2051
    2 = 2040

A take stores the calibration it was recorded with as one JSON record,
``{"zero_ticks": {"1": 2051, "2": 2040}}``: ``to_record`` writes it (``record``), ``from_record``
reads it back (``replay``, ``perform``, the view); one codec, checked as a file is.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet.rig.errors import RigError

INT32 = (-(2**31), 2**31 - 1)
"""Range of a servo's Present Position, hence of zero ticks."""


@dataclass
class Calibration:
    """Zero ticks per servo id.

    zero_ticks: {servo id: int32 encoder ticks at the rest pose}.
    path:       the file this came from or was saved to, if any.
    """

    zero_ticks: dict[int, int] = field(default_factory=dict)
    path: Path | None = None

    @classmethod
    def capture(cls, ids, ticks) -> "Calibration":
        """Zero pose capture: the puppet is held in the rest pose and read once.

        ids: (k,) servo ids; ticks: (k,) int32 readings in the same order.
        """
        ids = np.asarray(ids).reshape(-1)
        ticks = np.asarray(ticks).reshape(-1)
        if len(ids) != len(ticks):
            raise RigError(f"{len(ids)} ids but {len(ticks)} tick readings", field="calibration.capture")
        if len(set(ids.tolist())) != len(ids):
            raise RigError(f"duplicate servo ids in {ids.tolist()}", field="calibration.capture")
        return cls({int(i): int(t) for i, t in zip(ids, ticks)})

    def zero_for(self, servo_id: int, default: int) -> int:
        return self.zero_ticks.get(int(servo_id), int(default))

    def _doc(self) -> dict:
        return {"zero_ticks": {str(i): int(t) for i, t in sorted(self.zero_ticks.items())}}

    def to_record(self) -> str:
        """The calibration record a take stores: one line of JSON, ids in order."""
        return json.dumps(self._doc())

    @classmethod
    def from_record(cls, text: str, take) -> "Calibration":
        """The calibration a take was recorded with, from its record (``to_record``'s text; ""
        for a take that stores none: no zero ticks). RigError naming the take file and the entry
        at fault when the record is not such a text."""
        if not text:
            return cls()
        try:
            doc = json.loads(text)
        except (ValueError, RecursionError) as err:
            raise RigError(f"not valid JSON: {err}", path=take, field="calibration record") from None
        return cls(_zero_table(doc, take, "calibration record "))

    def save(self, path, *, inputs=(), force: bool = False,
             what: str = "calibration file") -> Path:
        """Write to ``path`` (.json for JSON, anything else TOML) atomically by
        ``puppet.atomic``'s rule (not one of ``inputs``; another kind of file only with
        ``force``); returns the path."""
        from puppet.atomic import atomic_output

        path = Path(path)
        items = sorted(self.zero_ticks.items())
        if path.suffix.lower() == ".json":
            text = json.dumps(self._doc(), indent=2) + "\n"
        else:
            lines = ["# puppet calibration: encoder ticks at the rig's rest pose", "[zero_ticks]"]
            lines += [f"{i} = {t}" for i, t in items]
            text = "\n".join(lines) + "\n"
        try:
            with atomic_output(path, kind="calibration", inputs=inputs, force=force,
                               what=what) as temporary:
                temporary.write_text(text)
        except OSError as err:
            raise RigError(f"cannot write calibration: {err.strerror}", path=path) from err
        self.path = path
        return path

    @classmethod
    def load(cls, path) -> "Calibration":
        """Read a calibration file; errors name the file and the servo entry at fault."""
        path = Path(path)
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            raise RigError("calibration file not found", path=path) from None
        except OSError as err:
            raise RigError(f"cannot read calibration: {err.strerror}", path=path) from err
        try:
            if path.suffix.lower() == ".json":
                doc = json.loads(raw)
            else:
                doc = tomllib.loads(raw.decode("utf-8"))
        except (json.JSONDecodeError, tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError) as err:
            raise RigError(f"not valid {'JSON' if path.suffix.lower() == '.json' else 'TOML'}: {err}",
                           path=path) from err
        return cls(_zero_table(doc, path), path)


def _zero_table(doc, path, where: str = "") -> dict[int, int]:
    """{id: ticks} of a parsed calibration document; RigError naming ``path`` and the entry."""
    table = doc.get("zero_ticks") if isinstance(doc, dict) else None
    if not isinstance(table, dict):
        raise RigError("missing table [zero_ticks]", path=path, field=f"{where}zero_ticks")
    zero = {}
    for key, value in table.items():
        try:
            servo_id = int(key)
        except ValueError:
            raise RigError(f"servo id {key!r} is not an integer", path=path,
                           field=f"{where}zero_ticks.{key}") from None
        if not 0 <= servo_id <= 252:
            raise RigError(f"servo id {servo_id} is not in 0..252", path=path,
                           field=f"{where}zero_ticks.{key}")
        if isinstance(value, bool) or not isinstance(value, int) or not INT32[0] <= value <= INT32[1]:
            raise RigError(f"zero ticks must be a 32-bit integer, got {value!r}", path=path,
                           field=f"{where}zero_ticks.{key}")
        zero[servo_id] = value
    return zero
