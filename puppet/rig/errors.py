"""Typed errors of the rig part: every message names the file and the field at fault."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from puppet.errors import PuppetError


class RigError(PuppetError, ValueError):
    """A rig file or rig object is invalid.

    path:  the file at fault, or None for in-memory data.
    field: the field, key or record at fault (e.g. "servo 7 limits", "accessor 3").
    line:  1-based line in ``path`` where the fault is, when known.
    message: the fault alone, without the place (``str(err)`` has both).
    """

    def __init__(self, message: str, *, path: object = None, field: str | None = None,
                 line: int | None = None) -> None:
        self.message = message
        self.path = None if path is None else str(path)
        self.field = field
        self.line = line
        where = self.path or "<rig>"
        if line is not None:
            where += f":{line}"
        if field:
            where += f": {field}"
        super().__init__(f"{where}: {message}")

    def at(self, path) -> "RigError":
        """This error placed in ``path`` when it names no file yet (in-memory data read from it)."""
        if self.path is not None:
            return self
        return RigError(self.message, path=path, field=self.field, line=self.line)


def check_regular_file(path: Path, what: str) -> None:
    """RigError naming ``path`` unless it is missing (the reader reports that) or a regular file:
    a FIFO, device or socket would block or never end when read."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as err:
        raise RigError(f"cannot read {what}: {err.strerror or err}", path=path) from None
    if stat.S_ISDIR(mode):
        raise RigError(f"is a folder, not a {what}", path=path)
    if not stat.S_ISREG(mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a device" if
                stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode)
                else "not a regular file")
        raise RigError(f"is {kind}, not a {what} (only regular files are read)", path=path)
