"""The session index: shots, numbered takes, notes, circled, locked, segments, as one JSON file.

    {"format": "puppet session", "version": 1, "created": "2026-11-29T09:30:00Z",
     "current_shot": "walk",
     "shots": [{"key": "walk", "name": "walk, slow", "created": "...",
                "takes": [{"number": 1, "file": "takes/walk/take001.mcap",
                           "date": "2026-11-29T09:31:12Z", "rig": "critter",
                           "duration_s": 12.4, "readings": 372, "note": "", "circled": true,
                           "locked": false, "trashed": false,
                           "segments": [{"name": "step", "in_s": 1.0, "out_s": 3.5,
                                         "loop": true}],
                           "layer_over": null}]}]}

Dates are UTC, ISO 8601. ``duration_s`` is seconds from the take's first reading to its last
(None when the take could not be read); a segment's ``in_s`` / ``out_s`` are seconds on the same
clock (0 = the first reading). ``layer_over`` (optional: absent reads as null) is the base of a
layer take (``puppet live --over``, "record a layer" on the page): its ``file`` when the base is a
take of this session (takes/walk/take003.mcap), else its absolute path; null for a take of its
own. ``file`` is where the take lives (``layout.take_file``), written
for a person reading the index; a trashed take lies at ``layout.trash_file`` instead.

``decode`` checks every field and raises IndexDamaged naming the first bad one
(``shots[0].takes[2].duration_s: must be a number``); ``read`` / ``write`` move the file (write:
whole or not at all, ``puppet.atomic``). Bounds: ``puppet.limits`` (SESSION_TAKES,
SESSION_SHOTS, NOTE_CHARS, NAME_CHARS, SEGMENTS_PER_TAKE, INDEX_BYTES).
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from puppet import limits
from puppet.atomic import atomic_output
from puppet.studio import layout
from puppet.studio.errors import IndexDamaged, IndexTooNew

FORMAT = "puppet session"
VERSION = 1
LAYER_OVER_CHARS = 4096
"""A layer's base path in the index: at most this long (a path, PATH_MAX)."""


def utc_text(unix_ns: int | None = None) -> str:
    """'2026-11-29T09:30:00Z' for a time in ns since the Unix epoch (now when None)."""
    seconds = time.time() if unix_ns is None else unix_ns / 1e9
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(seconds))


@dataclass
class Segment:
    """A named clip of a take: in_s < out_s, seconds from the take's first reading; loop: its
    seam is blended so that it plays as a loop."""

    name: str
    in_s: float
    out_s: float
    loop: bool = False


@dataclass
class Take:
    """Take ``number`` of its shot.

    file: path relative to the session folder (takes/<shot>/takeNNN.mcap); date: when recording
    started (UTC, ISO 8601); rig: the rig's name it was recorded with (None: unreadable take);
    duration_s: first to last reading, seconds (None: unreadable); readings: how many; note:
    the user's words (at most limits.NOTE_CHARS); circled: a good one; locked: read-only (no
    note, circle, segment or delete); trashed: in the session's trash (restorable);
    layer_over: the base of a layer take (the base's ``file`` when it is a take of the session,
    else its absolute path), None for a take of its own."""

    number: int
    file: str
    date: str
    rig: str | None
    duration_s: float | None
    readings: int
    note: str = ""
    circled: bool = False
    locked: bool = False
    trashed: bool = False
    segments: list[Segment] = field(default_factory=list)
    layer_over: str | None = None


@dataclass
class Shot:
    """A shot: ``key`` is its folder below takes/ (fixed), ``name`` what the user calls it
    (renamable); takes in number order."""

    key: str
    name: str
    created: str
    takes: list[Take] = field(default_factory=list)

    def take(self, number: int) -> Take | None:
        return next((t for t in self.takes if t.number == number), None)

    def next_number(self) -> int:
        """The number the shot's next recording gets: one past every number it ever gave
        (trashed takes keep theirs)."""
        return max((t.number for t in self.takes), default=0) + 1


@dataclass
class Index:
    """Everything the index file holds. current_shot: the key of the shot new recordings go
    to (None before the first shot)."""

    created: str
    current_shot: str | None = None
    shots: list[Shot] = field(default_factory=list)

    def shot(self, key: str) -> Shot | None:
        return next((s for s in self.shots if s.key == key), None)

    def takes(self) -> list[tuple[Shot, Take]]:
        """Every (shot, take), trashed ones included, in shot then number order."""
        return [(shot, take) for shot in self.shots for take in shot.takes]

    def take_count(self) -> int:
        return sum(len(shot.takes) for shot in self.shots)


def encode(index: Index) -> dict:
    """The index as the JSON object the file holds."""
    return {"format": FORMAT, "version": VERSION, **asdict(index)}


def encode_take(take: Take) -> dict:
    """One take as the JSON object the index holds for it."""
    return asdict(take)


def decode(data, where: str = layout.INDEX) -> Index:
    """An Index from the file's JSON object; IndexDamaged naming the first bad field, IndexTooNew
    for a newer version."""
    check = _Fields(where)
    root = check.object(data, "")
    if root.get("format") != FORMAT:
        raise IndexDamaged(f"{where}: not a puppet session index (format {root.get('format')!r}, "
                           f"expected {FORMAT!r})")
    version = root.get("version")
    if isinstance(version, int) and not isinstance(version, bool) and version > VERSION:
        raise IndexTooNew(f"{where}: written by a newer puppet (index version {version}); this "
                          f"puppet reads version {VERSION}: use the newer one")
    if version != VERSION:
        raise IndexDamaged(f"{where}: version: must be {VERSION}, got {version!r}")
    shots_data = check.list(root, "shots", "", limits.SESSION_SHOTS)
    index = Index(created=check.text(root, "created", "", 40),
                  current_shot=check.text(root, "current_shot", "", layout.KEY_CHARS, none=True))
    keys: set[str] = set()
    names: set[str] = set()
    count = 0
    for i, item in enumerate(shots_data):
        at = f"shots[{i}]"
        shot_data = check.object(item, at)
        key = check.text(shot_data, "key", at, layout.KEY_CHARS)
        if not layout.is_shot_key(key) or key.casefold() in keys:
            raise IndexDamaged(f"{where}: {at}.key: {key!r} is not a shot folder name, or twice")
        name = check.text(shot_data, "name", at, limits.NAME_CHARS)
        if not name.strip() or name.casefold() in names:
            raise IndexDamaged(f"{where}: {at}.name: {name!r} is empty or names two shots")
        keys.add(key.casefold())
        names.add(name.casefold())
        shot = Shot(key=key, name=name, created=check.text(shot_data, "created", at, 40))
        takes_data = check.list(shot_data, "takes", at, limits.SESSION_TAKES)
        count += len(takes_data)
        if count > limits.SESSION_TAKES:
            raise IndexDamaged(f"{where}: more than {limits.SESSION_TAKES} takes "
                               "(limits.SESSION_TAKES)")
        for j, take_item in enumerate(takes_data):
            shot.takes.append(_decode_take(check, take_item, f"{at}.takes[{j}]", key))
        numbers = [t.number for t in shot.takes]
        if len(set(numbers)) != len(numbers):
            raise IndexDamaged(f"{where}: {at}.takes: a take number is given twice ({numbers})")
        shot.takes.sort(key=lambda t: t.number)
        index.shots.append(shot)
    if index.current_shot is not None and index.shot(index.current_shot) is None:
        raise IndexDamaged(f"{where}: current_shot: {index.current_shot!r} is not a shot's key")
    return index


def _decode_take(check: "_Fields", item, at: str, key: str) -> Take:
    data = check.object(item, at)
    number = check.integer(data, "number", at, limits.TAKE_NUMBER)
    file = check.text(data, "file", at, 200)
    if file != layout.take_file(key, number):
        raise IndexDamaged(f"{check.where}: {at}.file: {file!r}, expected "
                           f"{layout.take_file(key, number)!r} (the shot's folder and number)")
    take = Take(number=number, file=file, date=check.text(data, "date", at, 40),
                rig=check.text(data, "rig", at, 200, none=True),
                duration_s=check.number(data, "duration_s", at, none=True),
                readings=check.integer(data, "readings", at, None),
                note=check.text(data, "note", at, limits.NOTE_CHARS),
                circled=check.flag(data, "circled", at), locked=check.flag(data, "locked", at),
                trashed=check.flag(data, "trashed", at),
                layer_over=(check.text(data, "layer_over", at, LAYER_OVER_CHARS, none=True)
                            if "layer_over" in data else None))
    segments = check.list(data, "segments", at, limits.SEGMENTS_PER_TAKE)
    for s, segment_item in enumerate(segments):
        sat = f"{at}.segments[{s}]"
        seg = check.object(segment_item, sat)
        segment = Segment(name=check.text(seg, "name", sat, limits.NAME_CHARS),
                          in_s=check.number(seg, "in_s", sat),
                          out_s=check.number(seg, "out_s", sat),
                          loop=check.flag(seg, "loop", sat))
        if not 0 <= segment.in_s < segment.out_s:
            raise IndexDamaged(f"{check.where}: {sat}: in_s {segment.in_s} and out_s "
                               f"{segment.out_s}: need 0 <= in_s < out_s")
        take.segments.append(segment)
    return take


class _Fields:
    """Reads fields of the index's JSON objects, raising IndexDamaged naming the field."""

    def __init__(self, where: str):
        self.where = where

    def _bad(self, at: str, name: str, what: str, value) -> IndexDamaged:
        path = f"{at}.{name}" if at else name
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
        return IndexDamaged(f"{self.where}: {path}: must be {what}, got {shown}")

    def object(self, value, at: str) -> dict:
        if not isinstance(value, dict):
            raise IndexDamaged(f"{self.where}: {at or 'the file'}: must be a JSON object")
        return value

    def _get(self, data: dict, name: str, at: str):
        if name not in data:
            raise IndexDamaged(f"{self.where}: {f'{at}.' if at else ''}{name}: missing")
        return data[name]

    def text(self, data, name, at, most: int, none: bool = False) -> str | None:
        value = self._get(data, name, at)
        if value is None and none:
            return None
        if not isinstance(value, str) or len(value) > most:
            raise self._bad(at, name, f"a string of at most {most} characters", value)
        return value

    def integer(self, data, name, at, bound) -> int:
        value = self._get(data, name, at)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0 or (
                bound is not None and not bound.holds(value)):
            raise self._bad(at, name, str(bound) if bound else "an integer >= 0", value)
        return value

    def number(self, data, name, at, none: bool = False) -> float | None:
        value = self._get(data, name, at)
        if value is None and none:
            return None
        if (isinstance(value, bool) or not isinstance(value, (int, float))
                or not math.isfinite(value) or value < 0):
            raise self._bad(at, name, "a number >= 0", value)
        return float(value)

    def flag(self, data, name, at) -> bool:
        value = self._get(data, name, at)
        if not isinstance(value, bool):
            raise self._bad(at, name, "true or false", value)
        return value

    def list(self, data, name, at, most: int) -> list:
        value = self._get(data, name, at)
        if not isinstance(value, list) or len(value) > most:
            raise self._bad(at, name, f"a list of at most {most} items", value)
        return value


def read(path: str | os.PathLike) -> Index:
    """The index in the file at ``path``; IndexDamaged (too large, not UTF-8 JSON, a bad
    field), IndexTooNew, or OSError (absent, unreadable)."""
    path = Path(path)
    with open(path, "rb") as handle:
        raw = handle.read(limits.INDEX_BYTES + 1)
    if len(raw) > limits.INDEX_BYTES:
        raise IndexDamaged(f"{path}: larger than {limits.INDEX_BYTES} bytes (limits.INDEX_BYTES)")
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise IndexDamaged(f"{path}: not a JSON file: {err}") from None
    return decode(data, str(path))


def text(index: Index) -> str:
    """The index file's text: indented JSON, UTF-8 characters as they are."""
    return json.dumps(encode(index), indent=2, ensure_ascii=False) + "\n"


def same_as_file(path: str | os.PathLike, index: Index) -> bool:
    """Whether the file at ``path`` holds exactly this index's text."""
    try:
        return Path(path).read_bytes() == text(index).encode("utf-8")
    except OSError:
        return False


def write(path: str | os.PathLike, index: Index) -> None:
    """Write the index to ``path`` whole (temporary file, flushed, renamed into place)."""
    with atomic_output(path, kind="text", force=True, what="session index") as temporary:
        temporary.write_text(text(index), encoding="utf-8")
