"""What the take files themselves say: a take's facts, the takes a folder holds, and an index
rebuilt from them when the index file is damaged or lost.

A rebuilt index has every take found in takes/ and trash/ (shots named after their folders,
takes numbered from their file names, date, rig, duration and readings read from each take);
what only the index held (shot names, notes, circled, locked, segments) cannot be recovered
from the takes: the damaged file is kept in the trash for a person to read.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from puppet import limits
from puppet.studio import layout
from puppet.studio.index import Index, Shot, Take, utc_text


@dataclass(frozen=True)
class TakeFacts:
    """What a take file says about itself: date (UTC ISO 8601, when recording started), rig
    (its rig's name), duration_s (first to last reading, s), readings (how many), layer_over
    (a layer's base: ``layer_base``); rig and duration_s are None, and problem says why, when
    the file cannot be read as a take."""

    date: str
    rig: str | None
    duration_s: float | None
    readings: int
    problem: str | None = None
    layer_over: str | None = None


def take_facts(path: str | os.PathLike) -> TakeFacts:
    """Read a take's facts (``puppet.take.TakeReader``: a damaged or truncated take still gives
    what it holds); an unreadable one gives its file's date and the reason."""
    from puppet.take import TakeError, TakeReader

    try:
        reader = TakeReader(path)
    except TakeError as err:
        return TakeFacts(_file_date(path), None, None, 0, err.reason)
    created = reader.metadata.created_unix_ns
    return TakeFacts(utc_text(created) if created > 0 else _file_date(path),
                     reader.metadata.rig_name, round(reader.duration_s, 6), len(reader),
                     layer_over=layer_base(reader))


def layer_base(reader) -> str | None:
    """The base of the layer take open in ``reader`` as the index names it: the base's ``file``
    (takes/<shot>/take003.mcap) when it is a take of the same session folder (the layer in
    takes/ or trash/), else its absolute path; None when the take is no layer."""
    from puppet.take.layers import base_path

    if reader.metadata.layer is None:
        return None
    base = base_path(reader).resolve()
    session = Path(reader.path).resolve().parent.parent.parent
    number = layout.take_number(base.name)
    if (number is not None and base.parent.parent in (session / layout.TAKES,
                                                      session / layout.TRASH)
            and layout.is_shot_key(base.parent.name)):
        return layout.take_file(base.parent.name, number)
    return str(base)


def _file_date(path) -> str:
    try:
        return utc_text(os.stat(path).st_mtime_ns)
    except OSError:
        return utc_text()


def new_take(shot_key: str, number: int, facts: TakeFacts, *, trashed: bool = False) -> Take:
    """An index entry for take ``number`` of a shot, from its facts."""
    return Take(number=number, file=layout.take_file(shot_key, number), date=facts.date,
                rig=facts.rig, duration_s=facts.duration_s, readings=facts.readings,
                trashed=trashed, layer_over=facts.layer_over)


def found_takes(folder: Path) -> dict[tuple[str, int], tuple[Path, bool]]:
    """{(shot key, number): (file, trashed)} of every take file below takes/ and trash/
    (``layout``'s names only; a take in both is listed from takes/), sorted; at most
    limits.SESSION_TAKES."""
    found: dict[tuple[str, int], tuple[Path, bool]] = {}
    for part, trashed in ((layout.TRASH, True), (layout.TAKES, False)):
        try:
            shots = sorted(p for p in (folder / part).iterdir() if p.is_dir())
        except OSError:
            continue
        for shot_folder in shots:
            if not layout.is_shot_key(shot_folder.name):
                continue
            for file in sorted(shot_folder.iterdir()):
                number = layout.take_number(file.name)
                if number is not None and limits.TAKE_NUMBER.holds(number) and file.is_file():
                    found[(shot_folder.name, number)] = (file, trashed)
                    if len(found) >= limits.SESSION_TAKES:
                        return dict(sorted(found.items()))
    return dict(sorted(found.items()))


def rebuild(folder: Path) -> tuple[Index, list[str]]:
    """An index of every take found in the folder, and the unreadable takes in words."""
    index = Index(created=utc_text())
    problems = adopt(index, folder)
    return index, problems


def adopt(index: Index, folder: Path) -> list[str]:
    """Add to ``index`` every take file found that it does not list (a shot made for a folder
    it does not know; the last shot made current when it has none); a listed take found only
    in the other place (takes/ or trash/) is marked so. Returns what was done, in words."""
    said: list[str] = []
    for (key, number), (file, trashed) in found_takes(folder).items():
        shot = index.shot(key)
        if shot is None:
            if len(index.shots) >= limits.SESSION_SHOTS:
                said.append(f"{file}: not listed: the session has {limits.SESSION_SHOTS} shots "
                            "(limits.SESSION_SHOTS)")
                continue
            shot = Shot(key=key, name=_free_name(index, key), created=utc_text())
            index.shots.append(shot)
        take = shot.take(number)
        if take is None:
            if index.take_count() >= limits.SESSION_TAKES:
                said.append(f"{file}: not listed: the session has {limits.SESSION_TAKES} takes "
                            "(limits.SESSION_TAKES)")
                continue
            facts = take_facts(file)
            shot.takes.append(new_take(key, number, facts, trashed=trashed))
            shot.takes.sort(key=lambda t: t.number)
            where = "the trash" if trashed else "takes/"
            said.append(f"{file}: found in {where}, listed as shot {shot.name!r} take {number}"
                        + (f" (unreadable: {facts.problem})" if facts.problem else ""))
        elif take.trashed != trashed and not _at(folder, key, number, take.trashed):
            take.trashed = trashed
            said.append(f"{file}: shot {shot.name!r} take {number} found "
                        f"{'in the trash' if trashed else 'back in takes/'}: listed so")
    if index.current_shot is None and index.shots:
        index.current_shot = index.shots[-1].key
    return said


def _at(folder: Path, key: str, number: int, trashed: bool) -> bool:
    """Whether a take's file is where the index says it is."""
    relative = layout.trash_file(key, number) if trashed else layout.take_file(key, number)
    return (folder / relative).is_file()


def _free_name(index: Index, key: str) -> str:
    names = {s.name.casefold() for s in index.shots}
    name, n = key, 1
    while name.casefold() in names:
        n += 1
        name = f"{key} ({n})"
    return name
