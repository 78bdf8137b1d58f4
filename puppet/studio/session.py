"""The one writer of a session folder: shots, numbered takes, notes, circled, locked, trash,
segments. Every change is written to the index at once, whole (``puppet.studio.index.write``);
a change whose write fails is undone in memory and raised, naming the file.

    with SessionWriter.open("shoot") as session:      # made if new; locked (one studio)
        session.new_shot("walk")
        path = session.new_take_path()                # shoot/takes/walk/take001.mcap
        ... record a take into path (TakeWriter) ...
        session.add_take(path)                         # take 1 of "walk", with its facts
        session.circle("walk", 1)
        session.add_segment("walk", 1, "step", 0.5, 2.0, loop=True)

Rules: a locked take refuses every edit (note, circle, segment, delete) naming the lock; a
deleted take moves into trash/ and back on restore (nothing is deleted outright; its number is
never given again); a take file removed behind the studio's back is listed as missing; a
damaged index is rebuilt from the takes (the damaged file kept in trash/, ``notes`` says so);
a folder that cannot be written (a read-only disk) fails at open, and a disk too full to record
(``limits.SESSION_FREE_BYTES``) fails in ``new_take_path``, before recording, naming the folder.
"""

from __future__ import annotations

import copy
import errno
import functools
import math
import os
import threading
import time
import unicodedata
from contextlib import contextmanager
from pathlib import Path

from puppet import limits
from puppet.studio import layout, rebuild
from puppet.studio import index as index_file
from puppet.studio.errors import StudioError, TakeLocked
from puppet.studio.folder import SessionFolder, load
from puppet.studio.index import Segment, Shot, Take, utc_text
from puppet.studio.lock import SessionLock


def _one_at_a_time(method):
    """Run a public method of SessionWriter holding its mutex: threads of one studio (a page's
    handlers, a recording that ends) change the index one change at a time."""

    @functools.wraps(method)
    def serialised(self, *args, **kwargs):
        with self._mutex:
            return method(self, *args, **kwargs)

    return serialised


class SessionWriter(SessionFolder):
    """A session folder opened for writing, holding its lock until ``close()``; its methods may
    be called from several threads (one change at a time).

    folder, index, notes: as SessionFolder (notes also say a stale lock taken over, a rebuilt
    index written); lock: the SessionLock held."""

    def __init__(self, folder: Path, index, notes: list[str], lock: SessionLock):
        super().__init__(folder, index, notes)
        self.lock = lock
        self._mutex = threading.RLock()

    @classmethod
    def open(cls, folder: str | os.PathLike, *, create: bool = True) -> "SessionWriter":
        """Open (and with ``create``, make) the session in ``folder`` and take its lock.

        StudioError naming the folder when it is not a session folder (a file, a folder of
        other things), cannot be made or written (a read-only disk); SessionInUse naming the
        studio that holds it; IndexTooNew when a newer puppet wrote its index."""
        folder = Path(folder)
        if folder.exists() and not folder.is_dir():
            raise StudioError(f"{folder}: exists and is not a folder; a session is a folder")
        if not folder.exists():
            if not create:
                raise StudioError(f"{folder}: no such session folder")
            try:
                folder.mkdir(parents=True)
            except OSError as err:
                raise StudioError(f"{folder}: cannot create the session folder: "
                                  f"{err.strerror or err}") from None
        elif not layout.is_session(folder) and any(folder.iterdir()):
            raise StudioError(f"{folder}: holds other files and is not a session folder (no "
                              f"{layout.INDEX}, no {layout.TAKES}/): choose a new or empty folder")
        lock = SessionLock(folder).acquire()
        try:
            return cls._open_locked(folder, lock)
        except BaseException:
            lock.release()
            raise

    @classmethod
    def _open_locked(cls, folder: Path, lock: SessionLock) -> "SessionWriter":
        notes = []
        for stale in folder.glob(".session.*.partial.json"):  # a killed writer's temporary
            stale.unlink(missing_ok=True)
        if lock.took_over:
            notes.append(f"{lock.path}: took over the lock of {lock.took_over}")
        for part in (layout.TAKES, layout.TRASH, layout.EXPORTS):
            try:
                (folder / part).mkdir(exist_ok=True)
            except OSError as err:
                raise StudioError(f"{folder / part}: cannot create it in the session folder: "
                                  f"{err.strerror or err}") from None
        index, found, damaged = load(folder)
        session = cls(folder, index, notes + found, lock)
        if damaged is not None and (folder / layout.INDEX).exists():
            kept = session._keep_damaged_index()
            session.notes.append(f"the damaged index is kept as {kept}")
        session.notes += rebuild.adopt(index, folder)
        if not index_file.same_as_file(folder / layout.INDEX, index):
            session._write()  # new, rebuilt or takes found: an unchanged index is not rewritten
        return session

    @_one_at_a_time
    def listing(self) -> dict:
        """As SessionFolder.listing, never in the middle of a change."""
        return super().listing()

    @_one_at_a_time
    def close(self) -> None:
        """Let go of the session (its lock); safe to call twice."""
        self.lock.release()

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- shots ----
    @_one_at_a_time
    def new_shot(self, name: str) -> Shot:
        """A new shot called ``name`` (unique, at most limits.NAME_CHARS), now the current one."""
        name = self._name(name, "shot name")
        self._free_shot_name(name)
        if len(self.index.shots) >= limits.SESSION_SHOTS:
            raise StudioError(f"{self.folder}: the session has {limits.SESSION_SHOTS} shots "
                              "(limits.SESSION_SHOTS): start another session")
        key = layout.shot_key(name, {s.key for s in self.index.shots} | self._folders())
        shot = Shot(key=key, name=name, created=utc_text())
        folder = self.folder / layout.TAKES / key
        try:  # its takes' folder, there at once: a take recorded into it is listed on next open
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise StudioError(f"{folder}: cannot make the shot's folder: {err.strerror or err}") from None
        with self._change():
            self.index.shots.append(shot)
            self.index.current_shot = key
        return shot

    @_one_at_a_time
    def use_shot(self, shot: str) -> Shot:
        """Make shot ``shot`` (a name or a folder name) the one new recordings go to."""
        found = self.shot(shot)
        with self._change():
            self.index.current_shot = found.key
        return found

    @_one_at_a_time
    def rename_shot(self, shot: str, name: str) -> Shot:
        """Call shot ``shot`` ``name`` from now on (its folder keeps its name: no file moves)."""
        found = self.shot(shot)
        name = self._name(name, "shot name")
        if name != found.name:
            self._free_shot_name(name, but=found)
            with self._change():
                found.name = name
        return found

    # ---- recording ----
    @_one_at_a_time
    def new_take_path(self) -> Path:
        """Where the current shot's next take is to be recorded (takes/<shot>/takeNNN.mcap; a
        first shot "shot 1" is made when there is none). Checked before recording: the bounds,
        that the folder can be written, and that its disk has limits.SESSION_FREE_BYTES free;
        StudioError naming the folder otherwise."""
        self._check_held()
        if self.index.take_count() >= limits.SESSION_TAKES:
            raise StudioError(f"{self.folder}: the session has {limits.SESSION_TAKES} takes "
                              "(limits.SESSION_TAKES): start another session")
        shot = self.current_shot or self.new_shot(self._first_shot_name())
        shot_folder = self.folder / layout.TAKES / shot.key
        number = shot.next_number()
        while (shot_folder / layout.take_name(number)).exists() or (
                self.folder / layout.trash_file(shot.key, number)).exists():
            number += 1  # a file no index lists (copied in by a person): never written over
        if not limits.TAKE_NUMBER.holds(number):
            raise StudioError(f"{self.folder}: shot {shot.name!r} has given every take number "
                              f"({limits.TAKE_NUMBER}): start a new shot")
        try:
            shot_folder.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise StudioError(f"{shot_folder}: cannot create the shot's folder: "
                              f"{err.strerror or err}") from None
        check_recordable(shot_folder, self.folder)
        return shot_folder / layout.take_name(number)

    @_one_at_a_time
    def add_take(self, path: str | os.PathLike) -> Take:
        """List the take just recorded at ``path`` (from ``new_take_path``) as take N of its
        shot, with its date, rig, duration and readings read from the file."""
        self._check_held()
        path = Path(path)
        shot, number = self._slot(path)
        if not path.is_file():
            raise StudioError(f"{path}: no take file there to add")
        if shot.take(number) is not None:
            raise StudioError(f"{path}: shot {shot.name!r} already lists take {number}")
        if self.index.take_count() >= limits.SESSION_TAKES:
            raise StudioError(f"{self.folder}: the session has {limits.SESSION_TAKES} takes "
                              "(limits.SESSION_TAKES)")
        take = rebuild.new_take(shot.key, number, rebuild.take_facts(path))
        with self._change():
            shot.takes.append(take)
            shot.takes.sort(key=lambda t: t.number)
        return take

    # ---- a take's marks ----
    @_one_at_a_time
    def note(self, shot: str, number: int, text: str) -> Take:
        """Set take ``number``'s note (at most limits.NOTE_CHARS; "" clears it)."""
        found, take = self._editable(shot, number, "change its note")
        if not isinstance(text, str) or len(text) > limits.NOTE_CHARS:
            raise StudioError(f"note: at most {limits.NOTE_CHARS} characters "
                              f"(limits.NOTE_CHARS), got {len(text)}")
        bad = next((c for c in text if unicodedata.category(c) == "Cc" and c not in "\n\t"),
                   None)
        if bad is not None:
            raise StudioError(f"note: holds the control character {bad!r}")
        with self._change():
            take.note = text
        return take

    @_one_at_a_time
    def circle(self, shot: str, number: int, circled: bool = True) -> Take:
        """Circle take ``number`` (a good one), or uncircle it."""
        _, take = self._editable(shot, number, "circle it" if circled else "uncircle it")
        with self._change():
            take.circled = bool(circled)
        return take

    @_one_at_a_time
    def lock_take(self, shot: str, number: int, locked: bool = True) -> Take:
        """Lock take ``number`` (read-only: no note, circle, segment or delete), or unlock it."""
        found, take = self.take(shot, number)
        if take.trashed:
            raise StudioError(f"{self.folder}: shot {found.name!r} take {number} is in the "
                              "trash: restore it first")
        with self._change():
            take.locked = bool(locked)
        return take

    # ---- trash ----
    @_one_at_a_time
    def delete(self, shot: str, number: int) -> Take:
        """Move take ``number`` into the session's trash (restorable: ``restore``)."""
        found, take = self._editable(shot, number, "delete it")
        source = self.folder / layout.take_file(found.key, number)
        target = self.folder / layout.trash_file(found.key, number)
        if target.exists():
            raise StudioError(f"{target}: a file is already there (put there by hand?): move it "
                              f"away to delete shot {found.name!r} take {number}")
        self._move_with(take, source, target, trashed=True)
        return take

    @_one_at_a_time
    def restore(self, shot: str, number: int) -> Take:
        """Bring take ``number`` back from the trash."""
        found, take = self.take(shot, number)
        if not take.trashed:
            raise StudioError(f"{self.folder}: shot {found.name!r} take {number} is not in "
                              "the trash")
        source = self.folder / layout.trash_file(found.key, number)
        target = self.folder / layout.take_file(found.key, number)
        if target.exists():
            raise StudioError(f"{target}: a file is already there: move it away to restore "
                              f"shot {found.name!r} take {number}")
        self._move_with(take, source, target, trashed=False)
        return take

    # ---- segments ----
    @_one_at_a_time
    def add_segment(self, shot: str, number: int, name: str, in_s: float, out_s: float,
                    loop: bool = False) -> Segment:
        """A named clip of take ``number``: in_s < out_s, seconds from its first reading,
        within its duration; loop: play it as a loop (its seam blended)."""
        found, take = self._editable(shot, number, "add a segment")
        name = self._name(name, "segment name")
        same = next((s for s in take.segments if s.name.casefold() == name.casefold()), None)
        if same is not None:
            raise StudioError(f"{self.folder}: shot {found.name!r} take {number} has a segment "
                              f"{same.name!r} already")
        if len(take.segments) >= limits.SEGMENTS_PER_TAKE:
            raise StudioError(f"{self.folder}: shot {found.name!r} take {number} has "
                              f"{limits.SEGMENTS_PER_TAKE} segments (limits.SEGMENTS_PER_TAKE)")
        for what, value in (("in", in_s), ("out", out_s)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value) or value < 0:
                raise StudioError(f"segment {name!r}: {what} point must be a number of seconds "
                                  f">= 0, got {value!r}")
        if not in_s < out_s:
            raise StudioError(f"segment {name!r}: in point {in_s} s must come before the out "
                              f"point {out_s} s")
        if take.duration_s is not None and out_s > take.duration_s + 1e-6:
            raise StudioError(f"segment {name!r}: out point {out_s} s is past the end of shot "
                              f"{found.name!r} take {number} ({take.duration_s:.3f} s)")
        segment = Segment(name=name, in_s=float(in_s), out_s=float(out_s), loop=bool(loop))
        with self._change():
            take.segments.append(segment)
        return segment

    @_one_at_a_time
    def remove_segment(self, shot: str, number: int, name: str) -> Segment:
        """Remove take ``number``'s segment called ``name``."""
        found, take = self._editable(shot, number, "remove a segment")
        segment = next((s for s in take.segments if s.name == name), None) or next(
            (s for s in take.segments if s.name.casefold() == str(name).casefold()), None)
        if segment is None:
            names = ", ".join(repr(s.name) for s in take.segments) or "none"
            raise StudioError(f"{self.folder}: shot {found.name!r} take {number} has no segment "
                              f"{name!r} (segments: {names})")
        with self._change():
            take.segments.remove(segment)
        return segment

    # ---- the one write ----
    @contextmanager
    def _change(self):
        """Apply a change to the index in memory, then write it; undone when the write fails."""
        self._check_held()
        before = copy.deepcopy(self.index)
        try:
            yield
            self._write()
        except BaseException:
            self.index = before
            raise

    def _write(self) -> None:
        path = self.folder / layout.INDEX
        try:
            index_file.write(path, self.index)
        except OSError as err:
            full = " (the disk is full)" if err.errno == errno.ENOSPC else ""
            raise StudioError(f"{path}: cannot write the session's index{full}: "
                              f"{err.strerror or err}; the change was not made") from None

    def _move_with(self, take: Take, source: Path, target: Path, *, trashed: bool) -> None:
        """Move a take's file (when it is there) and mark it, as one change: the file goes back
        when the index cannot be written."""
        moved = source.is_file()
        if moved:
            target.parent.mkdir(parents=True, exist_ok=True)
            os.rename(source, target)
        try:
            with self._change():
                take.trashed = trashed
        except BaseException:
            if moved:
                os.rename(target, source)
            raise

    def _keep_damaged_index(self) -> Path:
        """Move the damaged index into trash/ (never deleted): its new name."""
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        target = self.folder / layout.TRASH / f"session.damaged-{stamp}.json"
        n = 1
        while target.exists():
            n += 1
            target = target.with_name(f"session.damaged-{stamp}-{n}.json")
        os.rename(self.folder / layout.INDEX, target)
        return target

    # ---- checks ----
    def _check_held(self) -> None:
        if not self.lock.held:
            raise StudioError(f"{self.folder}: this session was closed: open it again to change it")

    def _editable(self, shot: str, number: int, action: str) -> tuple[Shot, Take]:
        found, take = self.take(shot, number)
        if take.locked:
            raise TakeLocked(self.folder, found.name, number, action)
        if take.trashed:
            raise StudioError(f"{self.folder}: shot {found.name!r} take {number} is in the "
                              f"trash: restore it first to {action}")
        return found, take

    def _slot(self, path: Path) -> tuple[Shot, int]:
        """(shot, number) of a path new_take_path gave; StudioError for any other path."""
        number = layout.take_number(path.name)
        shot = self.index.shot(path.parent.name)
        takes = self.folder / layout.TAKES
        if (number is None or shot is None
                or path.parent.parent.resolve() != takes.resolve()):
            raise StudioError(f"{path}: not a take path of session {self.folder} (record into "
                              f"the path new_take_path gives: {layout.TAKES}/<shot>/takeNNN.mcap)")
        return shot, number

    def _folders(self) -> set[str]:
        """Shot folders already on disk (a key is never one of another shot's trash)."""
        names = set()
        for part in (layout.TAKES, layout.TRASH):
            try:
                names |= {p.name for p in (self.folder / part).iterdir()}
            except OSError:
                pass
        return names

    def _first_shot_name(self) -> str:
        names = {s.name.casefold() for s in self.index.shots}
        n = 1
        while f"shot {n}" in names:
            n += 1
        return f"shot {n}"

    @staticmethod
    def _name(name, what: str) -> str:
        if not isinstance(name, str) or not name.strip():
            raise StudioError(f"{what}: must not be empty")
        name = name.strip()
        if len(name) > limits.NAME_CHARS:
            raise StudioError(f"{what}: at most {limits.NAME_CHARS} characters "
                              f"(limits.NAME_CHARS), got {len(name)}")
        bad = next((c for c in name if unicodedata.category(c) == "Cc"), None)
        if bad is not None:
            raise StudioError(f"{what} {name!r}: holds the control character {bad!r}")
        return name

    def _free_shot_name(self, name: str, but: Shot | None = None) -> None:
        other = next((s for s in self.index.shots
                      if s is not but and s.name.casefold() == name.casefold()), None)
        if other is not None:
            raise StudioError(f"{self.folder}: a shot is called {other.name!r} already")


def check_recordable(folder: Path, session: Path) -> None:
    """StudioError naming ``folder`` unless a file can be made in it and its disk has
    limits.SESSION_FREE_BYTES free (a read-only or full disk fails before recording)."""
    probe = folder / f".puppet-probe.{os.getpid()}"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        full = " (the disk is full)" if err.errno == errno.ENOSPC else ""
        raise StudioError(f"{folder}: cannot record into session {session}{full}: "
                          f"{err.strerror or err}") from None
    try:
        stats = os.statvfs(folder)
    except OSError:
        return  # a file system that does not tell: the take writer reports a full disk
    free = stats.f_bavail * stats.f_frsize
    if free < limits.SESSION_FREE_BYTES:
        raise StudioError(f"{folder}: cannot record into session {session}: its disk has "
                          f"{free / 2**20:.1f} MiB free, a recording needs at least "
                          f"{limits.SESSION_FREE_BYTES / 2**20:.0f} MiB "
                          "(limits.SESSION_FREE_BYTES): free some space")
