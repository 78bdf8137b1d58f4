"""The servos of a puppet rig file, read device-side: what ``hw-sim --rig RIG`` serves.

hw_sim imports nothing of ``puppet``: this reads the rig TOML's ``[[servo]]`` tables itself
(``id``, ``model``, ``zero_ticks``, ``sign``, ``gear``, ``limits_deg``) and, when the rig names a
``calibration`` file that exists, its ``[zero_ticks]`` table (the host's zero overrides the
map's, as in puppet). Only what the simulator needs is checked here; puppet checks the rest.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from hw_sim.control_table import MODELS
from hw_sim.errors import _FileLineError


class RigFileError(_FileLineError):
    """A rig file whose servos hw_sim cannot serve."""


@dataclass(frozen=True)
class RigServo:
    """One servo of a rig as the simulator needs it.

    id: bus id; model: model name; zero_ticks: counts at the rig's rest pose; sign: +1 or -1;
    gear: servo turns per joint turn; limits_deg: (low, high) joint limits, degrees.
    """

    id: int
    model: str
    zero_ticks: int = 2048
    sign: int = 1
    gear: float = 1.0
    limits_deg: tuple[float, float] = (-180.0, 180.0)


def _number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def read_rig_servos(path) -> list[RigServo]:
    """The rig's servos in file order; RigFileError naming the file (and servo) otherwise."""
    path = Path(path)
    if path.exists() and not path.is_file():  # a FIFO or device would block or never end
        raise RigFileError(path, None, "not a regular file (only regular files are read)")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RigFileError(path, None, f"cannot read rig file: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError) as exc:
        raise RigFileError(path, None, f"not a TOML rig file: {exc}") from None
    tables = doc.get("servo", [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables) or not tables:
        raise RigFileError(path, None, "no [[servo]] tables: nothing to serve")
    zero = _calibration(path, doc.get("calibration"))
    servos: list[RigServo] = []
    for k, table in enumerate(tables, 1):
        sid, model = table.get("id"), table.get("model")
        where = f"servo #{k}"
        if isinstance(sid, bool) or not isinstance(sid, int) or not 0 <= sid <= 252:
            raise RigFileError(path, None, f"{where}: id must be an integer 0..252, got {sid!r}")
        if any(s.id == sid for s in servos):
            raise RigFileError(path, None, f"{where}: servo id {sid} is listed twice")
        if not isinstance(model, str) or model not in MODELS:
            raise RigFileError(path, None, f"servo {sid}: hw_sim does not simulate model "
                                           f"{model!r} (known: {', '.join(MODELS)})")
        limits = table.get("limits_deg", [-180.0, 180.0])
        sign, gear = table.get("sign", 1), table.get("gear", 1.0)
        ticks = table.get("zero_ticks", 2048)
        if (not isinstance(limits, list) or len(limits) != 2 or not all(map(_number, limits))
                or sign not in (1, -1) or not _number(gear) or gear <= 0
                or isinstance(ticks, bool) or not isinstance(ticks, int)):
            raise RigFileError(path, None, f"servo {sid}: sign, gear, zero_ticks or limits_deg "
                                           "is invalid (run 'puppet rig info' on the file)")
        servos.append(RigServo(sid, model, int(zero.get(sid, ticks)), int(sign), float(gear),
                               (float(limits[0]), float(limits[1]))))
    return servos


def _calibration(rig_path: Path, name) -> dict[int, int]:
    """{id: zero ticks} from the rig's calibration file, or {} when it names none or it is absent."""
    if not isinstance(name, str) or not name:
        return {}
    path = rig_path.parent / name
    if not path.is_file():
        return {}
    try:
        text = path.read_text(encoding="utf-8")
        doc = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (OSError, UnicodeDecodeError, ValueError) as exc:  # TOMLDecodeError is a ValueError
        raise RigFileError(path, None, f"unreadable calibration file: {exc}") from None
    table = doc.get("zero_ticks", {}) if isinstance(doc, dict) else {}
    out = {}
    for key, value in table.items() if isinstance(table, dict) else ():
        if key.isdigit() and isinstance(value, int) and not isinstance(value, bool):
            out[int(key)] = value
    return out
