"""Where things live in a session folder: plain files a person can read.

    SESSION/
      session.json           the index (puppet.studio.index): shots, numbered takes, notes,
                             circled, locked, segments; written only by the studio that holds
                             the lock, whole (a temporary file renamed into place)
      session.lock           who holds the session (pid, command, since); empty when none
      takes/<shot>/take003.mcap   take 3 of the shot whose folder is <shot> (MCAP, as recorded)
      trash/<shot>/take002.mcap   a deleted take (restorable; nothing is deleted outright);
                                  a damaged index replaced by a rebuilt one is kept here too
      exports/               what exports write (puppet batch SESSION: exports/<shot>/take003.glb)

A shot's folder name (its key) is chosen once, from its first name, and never changes: renaming
a shot renames it in the index only, so no file moves under a running export or a reader.
"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

INDEX = "session.json"
LOCK = "session.lock"
TAKES = "takes"
TRASH = "trash"
EXPORTS = "exports"
TAKE_SUFFIX = ".mcap"
_TAKE_NAME = re.compile(r"^take(\d{3,})\.mcap$")
_KEY_CHARS = re.compile(r"[^A-Za-z0-9._-]+")
KEY_CHARS = 40  # a shot folder's name: short enough to read in a file browser


def is_session(folder: str | Path) -> bool:
    """Whether ``folder`` is a session folder: it holds an index or a takes/ folder (an index
    lost beside its takes is still a session: it is rebuilt)."""
    folder = Path(folder)
    return (folder / INDEX).is_file() or (folder / TAKES).is_dir()


def take_name(number: int) -> str:
    """'take003.mcap' for take 3."""
    return f"take{number:03d}{TAKE_SUFFIX}"


def take_number(name: str) -> int | None:
    """3 for 'take003.mcap'; None for any other file name."""
    match = _TAKE_NAME.match(name)
    return int(match[1]) if match else None


def take_file(shot_key: str, number: int) -> str:
    """The take's path relative to the session folder: 'takes/<shot>/take003.mcap'."""
    return f"{TAKES}/{shot_key}/{take_name(number)}"


def trash_file(shot_key: str, number: int) -> str:
    """Where a deleted take goes, relative to the session folder: 'trash/<shot>/take003.mcap'."""
    return f"{TRASH}/{shot_key}/{take_name(number)}"


def shot_key(name: str, taken: set[str]) -> str:
    """A folder name for a new shot called ``name``: its letters, digits, '.', '_' and '-'
    (accents dropped, other runs turned into '-'), at most KEY_CHARS, never hidden, unique
    among ``taken`` without regard to case (a '-2', '-3' ... is added)."""
    ascii_name = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode()
    key = _KEY_CHARS.sub("-", ascii_name).strip("-.")[:KEY_CHARS].strip("-.") or "shot"
    folded = {k.casefold() for k in taken}
    unique, n = key, 1
    while unique.casefold() in folded:
        n += 1
        unique = f"{key[:KEY_CHARS - len(str(n)) - 1]}-{n}"
    return unique


def is_shot_key(key: str) -> bool:
    """Whether ``key`` could be a shot folder's name (what shot_key makes)."""
    return (0 < len(key) <= KEY_CHARS and not _KEY_CHARS.search(key)
            and not key.startswith((".", "-")))
