"""One studio per session folder: an exclusive ``flock`` on SESSION/session.lock.

The holder writes who it is into the file (``pid 4242``, its command line, since when) so a
person can read it; a second studio is refused with SessionInUse naming the holder (from
``/proc/locks`` through ``puppet.lock_holder``, else from the file). The lock belongs to the
open file: a studio that ends, however it ends (even SIGKILL), releases it. A lock file still
naming a process that is gone (killed before it could empty the file) is taken over, and
``SessionLock.took_over`` says whose it was. Readers (``puppet batch SESSION``, ``puppet session
list``) take no lock: the index is only ever replaced whole.
"""

from __future__ import annotations

import errno
import fcntl
import os
import sys
from pathlib import Path

from puppet import lock_holder
from puppet.studio import layout
from puppet.studio.errors import SessionInUse, StudioError
from puppet.studio.index import utc_text


class SessionLock:
    """The lock of session ``folder``, taken at once (or SessionInUse) by ``acquire()``.

    took_over: the dead holder whose stale lock was taken over, in words, or None."""

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        self.path = self.folder / layout.LOCK
        self.took_over: str | None = None
        self._fd: int | None = None

    def acquire(self) -> "SessionLock":
        """Take the lock; SessionInUse naming the holder, StudioError naming the folder when
        the lock file cannot be made (a read-only disk, a folder of another user)."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise StudioError(f"{self.folder}: cannot write in the session folder "
                              f"({err.strerror or err}): a studio needs a writable folder"
                              ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = lock_holder.holder(fd) or _written_holder(fd)
            os.close(fd)
            raise SessionInUse(self.folder, holder) from None
        try:
            previous = _read(fd)
            os.ftruncate(fd, 0)
            text = (f"pid {os.getpid()}\ncommand {lock_holder.command(os.getpid()) or sys.argv[0]}"
                    f"\nsince {utc_text()}\n")
            os.pwrite(fd, text.encode(), 0)
            os.fsync(fd)
        except OSError as err:
            os.close(fd)
            full = " (the disk is full)" if err.errno == errno.ENOSPC else ""
            raise StudioError(f"{self.folder}: cannot write {self.path.name}{full}: "
                              f"{err.strerror or err}") from None
        self._fd = fd
        if previous.get("pid"):
            self.took_over = (f"pid {previous['pid']} ({previous.get('command', '?')}, since "
                              f"{previous.get('since', '?')}), which is no longer running")
        return self

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Empty the lock file and let go of it; safe to call twice."""
        if self._fd is None:
            return
        try:
            os.ftruncate(self._fd, 0)
        except OSError:
            pass  # a disk gone read-only: the kernel still releases the lock below
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> "SessionLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _read(fd: int) -> dict[str, str]:
    """{'pid': ..., 'command': ..., 'since': ...} from a lock file (empty when none)."""
    try:
        raw = os.pread(fd, 4096, 0).decode("utf-8", "replace")
    except OSError:
        return {}
    fields = {}
    for line in raw.splitlines():
        name, _, value = line.partition(" ")
        if name in ("pid", "command", "since"):
            fields[name] = value.strip()
    return fields


def _written_holder(fd: int) -> str | None:
    """The holder as its lock file names it (where /proc/locks cannot tell)."""
    fields = _read(fd)
    if not fields.get("pid"):
        return None
    return f"pid {fields['pid']} ({fields.get('command', '?')})"
