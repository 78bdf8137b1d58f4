"""Typed errors of the session folder; every message names the folder (and the shot and take)."""

from __future__ import annotations

from puppet.errors import PuppetError


class StudioError(PuppetError):
    """A session folder cannot be used as asked: not a session, not writable, a disk too full
    to record, an unknown shot or take, a bad name, note or segment, a bound reached."""


class SessionInUse(StudioError):
    """Another studio holds the session folder's lock.

    folder: the session folder; holder: that process in words ('pid 4242 (puppet studio s)'),
    or None when it cannot be told."""

    def __init__(self, folder, holder: str | None):
        self.folder = str(folder)
        self.holder = holder
        super().__init__(f"{self.folder}: session in use by {holder or 'another process'}: one "
                         "studio per session folder (stop that one first)")

    def __reduce__(self):
        return (SessionInUse, (self.folder, self.holder))


class TakeLocked(StudioError):
    """A locked take (read-only) was asked to change: a note, a circle, a segment, a delete."""

    def __init__(self, folder, shot: str, number: int, action: str):
        self.folder, self.shot, self.number, self.action = str(folder), shot, number, action
        super().__init__(f"{self.folder}: shot {shot!r} take {number} is locked (read-only): "
                         f"cannot {action}; unlock it first")

    def __reduce__(self):
        return (TakeLocked, (self.folder, self.shot, self.number, self.action))


class IndexDamaged(StudioError):
    """The index file cannot be read as a session index (not JSON, a field missing or of the
    wrong kind, too large); the studio rebuilds it from the takes."""


class IndexTooNew(StudioError):
    """The index was written by a newer puppet: never rebuilt over, never written."""
