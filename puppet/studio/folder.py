"""A session folder as it stands, read without the lock: what ``puppet batch SESSION`` and
``puppet session list`` see, and the base of the one writer (``puppet.studio.session``).

Reading never writes: a damaged or lost index is rebuilt in memory from the takes (said in
``notes``), takes on disk that the index does not list are listed, and a take whose file is
gone is listed as missing.
"""

from __future__ import annotations

import os
from pathlib import Path

from puppet.studio import layout, rebuild
from puppet.studio import index as index_file
from puppet.studio.errors import IndexDamaged, StudioError
from puppet.studio.index import Index, Shot, Take

OK = "ok"
MISSING = "missing"        # its file is not where the index says (removed behind the studio)
TRASHED = "trashed"        # in the session's trash, restorable
TRASHED_MISSING = "trashed, missing"
STATUSES = (OK, MISSING, TRASHED, TRASHED_MISSING)


class SessionFolder:
    """A session folder read as it is now (``SessionFolder.read(folder)``).

    folder: the session folder; index: its Index (rebuilt in memory when the file is damaged
    or absent); notes: what reading found, in words (a rebuilt index, takes found that the
    index did not list)."""

    def __init__(self, folder: Path, index: Index, notes: list[str]):
        self.folder = folder
        self.index = index
        self.notes = notes

    @classmethod
    def read(cls, folder: str | os.PathLike) -> "SessionFolder":
        """The session in ``folder``; StudioError when it is not a session folder, IndexTooNew
        when a newer puppet wrote it."""
        folder = Path(folder)
        if not folder.is_dir():
            raise StudioError(f"{folder}: no such session folder")
        if not layout.is_session(folder):
            raise StudioError(f"{folder}: not a session folder (no {layout.INDEX}, no "
                              f"{layout.TAKES}/)")
        index, notes, _ = load(folder)
        notes += rebuild.adopt(index, folder)
        return cls(folder, index, notes)

    # ---- finding ----
    def shot(self, ref: str) -> Shot:
        """The shot named ``ref`` (its name, else its folder's name); StudioError listing the
        shots when there is none."""
        found = (next((s for s in self.index.shots if s.name == ref), None)
                 or next((s for s in self.index.shots if s.name.casefold() == ref.casefold()), None)
                 or self.index.shot(ref))
        if found is None:
            names = ", ".join(repr(s.name) for s in self.index.shots) or "none yet"
            raise StudioError(f"{self.folder}: no shot {ref!r} (shots: {names})")
        return found

    def take(self, shot: str, number: int) -> tuple[Shot, Take]:
        """(shot, take) for take ``number`` of shot ``shot``; StudioError naming both if none."""
        found = self.shot(shot)
        take = found.take(number)
        if take is None:
            numbers = ", ".join(str(t.number) for t in found.takes) or "none yet"
            raise StudioError(f"{self.folder}: shot {found.name!r} has no take {number} "
                              f"(takes: {numbers})")
        return found, take

    @property
    def current_shot(self) -> Shot | None:
        """The shot new recordings go to (None before the first)."""
        key = self.index.current_shot
        return None if key is None else self.index.shot(key)

    # ---- where takes are ----
    def path(self, shot: Shot, take: Take) -> Path:
        """Where the take's file lies: in takes/, or in trash/ when trashed."""
        relative = (layout.trash_file(shot.key, take.number) if take.trashed
                    else layout.take_file(shot.key, take.number))
        return self.folder / relative

    def status(self, shot: Shot, take: Take) -> str:
        """One of STATUSES."""
        there = self.path(shot, take).is_file()
        if take.trashed:
            return TRASHED if there else TRASHED_MISSING
        return OK if there else MISSING

    def chosen(self, *, circled: bool = False) -> tuple[list[tuple[Shot, Take, Path]], list[str]]:
        """The takes to work on (export): every take not trashed, or only circled ones, whose
        file is there; and the missing ones in words."""
        chosen, missing = [], []
        for shot, take in self.index.takes():
            if take.trashed or (circled and not take.circled):
                continue
            path = self.path(shot, take)
            if self.status(shot, take) == MISSING:
                missing.append(f"{path}: shot {shot.name!r} take {take.number} is missing (its "
                               "file was removed or moved): skipped")
            else:
                chosen.append((shot, take, path))
        return chosen, missing

    def listing(self) -> dict:
        """The session as a JSON-ready dict: folder, current_shot (key), notes, shots (key,
        name, created, current, takes: every index field plus status and path)."""
        shots = []
        for shot in self.index.shots:
            takes = []
            for take in shot.takes:
                row = index_file.encode_take(take)
                row["status"] = self.status(shot, take)
                row["path"] = str(self.path(shot, take))
                takes.append(row)
            shots.append({"key": shot.key, "name": shot.name, "created": shot.created,
                          "current": shot.key == self.index.current_shot, "takes": takes})
        return {"folder": str(self.folder), "current_shot": self.index.current_shot,
                "notes": list(self.notes), "shots": shots}

    def table(self) -> str:
        """The listing as lines a person reads: one per take, the current shot marked."""
        lines = [f"session {self.folder}"]
        for shot in self.index.shots:
            mark = "  (current)" if shot.key == self.index.current_shot else ""
            lines.append(f"shot {shot.name!r} [{layout.TAKES}/{shot.key}/]{mark}")
            for take in shot.takes:
                flags = [f for f, on in (("circled", take.circled), ("locked", take.locked))
                         if on]
                status = self.status(shot, take)
                if status != OK:
                    flags.append(status)
                if take.layer_over is not None:
                    base = next((t for t in shot.takes if t.file == take.layer_over), None)
                    flags.insert(0, f"layer over take {base.number}" if base is not None
                                 else f"layer over {take.layer_over}")
                duration = "?" if take.duration_s is None else f"{take.duration_s:.2f} s"
                segments = f"  segments: {', '.join(s.name for s in take.segments)}" \
                    if take.segments else ""
                note = f"  note: {take.note!r}" if take.note else ""
                lines.append(f"  take {take.number:>3}  {take.date}  {take.rig or '?'}  "
                             f"{duration}  {' '.join(flags) or '-'}{note}{segments}")
            if not shot.takes:
                lines.append("  no takes yet")
        if not self.index.shots:
            lines.append("no shots yet")
        return "\n".join(lines)


def load(folder: Path) -> tuple[Index, list[str], str | None]:
    """The folder's index and notes; the third item is why the file could not be used
    (damaged, absent beside takes: the index was rebuilt from the takes), else None.
    IndexTooNew passes through (nothing is rebuilt over a newer index)."""
    path = folder / layout.INDEX
    try:
        return index_file.read(path), [], None
    except FileNotFoundError:
        if not rebuild.found_takes(folder):
            return Index(created=index_file.utc_text()), [], None  # a new session
        why = f"{path}: absent"
    except IndexDamaged as err:
        why = f"damaged ({err})"
    except OSError as err:
        why = f"{path}: cannot be read ({err.strerror or err})"
    index, problems = rebuild.rebuild(folder)
    takes = index.take_count()
    note = (f"{path}: the index was {why}; rebuilt from the {takes} take(s) in "
            f"{layout.TAKES}/ and {layout.TRASH}/ (shot names, notes, circled, locked and "
            "segments were only in the index)")
    return index, [note, *problems], why
