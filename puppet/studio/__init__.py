"""The studio's session folder: shots and numbered takes, their marks, a trash and exports, as
plain files a person can read (``layout``), with one writer of the index.

Public API:
    SessionWriter.open(folder, create=True) -> SessionWriter  (the one writer; holds the lock)
        .new_shot(name) -> Shot  .use_shot(shot) -> Shot  .rename_shot(shot, name) -> Shot
        .new_take_path() -> Path (checked: writable, free space)  .add_take(path) -> Take
        .note(shot, n, text) .circle(shot, n, circled=True) .lock_take(shot, n, locked=True)
        .delete(shot, n) .restore(shot, n) -> Take
        .add_segment(shot, n, name, in_s, out_s, loop=False) .remove_segment(shot, n, name)
        .close() (also as a context manager); .notes: what opening found and did
    SessionFolder.read(folder) -> SessionFolder  (read only, no lock: batch, listings)
        .index (Index: shots -> takes -> segments)  .notes  .shot(ref)  .take(ref, n)
        .current_shot  .path(shot, take)  .status(shot, take) (ok, missing, trashed, ...)
        .chosen(circled=False) -> ([(shot, take, path)], [missing in words])
        .listing() -> JSON-ready dict  .table() -> text
    is_session(folder) -> bool
    errors: StudioError > SessionInUse (holder), TakeLocked, IndexDamaged, IndexTooNew
A shot is named by its name (or its folder's name); a take by its shot and number.
"""

from puppet.studio.errors import IndexDamaged, IndexTooNew, SessionInUse, StudioError, TakeLocked
from puppet.studio.folder import STATUSES, SessionFolder
from puppet.studio.index import Index, Segment, Shot, Take
from puppet.studio.layout import is_session
from puppet.studio.session import SessionWriter

__all__ = [
    "Index",
    "IndexDamaged",
    "IndexTooNew",
    "STATUSES",
    "Segment",
    "SessionFolder",
    "SessionInUse",
    "SessionWriter",
    "Shot",
    "StudioError",
    "Take",
    "TakeLocked",
    "is_session",
]
