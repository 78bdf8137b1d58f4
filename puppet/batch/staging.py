"""Staging folders: where a batch's unfinished files live, and how the next run finds a dead one.

A driver stages in ``OUT/.puppet-batch.<host>.<pid>.partial/`` (local engine: its workers
write there, each take in ``<take name>.<worker pid>/``; the driver renames finished files
into OUT) and, on the Ray engine, tasks on this machine stage in the same-named folder in the
system's temporary folder. The driver holds an exclusive lock (``flock``) on ``.lock`` inside
each while it runs and removes them when it ends, however it ends (done, a failure, SIGINT,
SIGTERM). A driver that was killed (SIGKILL, a crash, the machine's power) cannot: the kernel
releases its lock, and the next batch writing into that folder (``--resume`` or not) takes the
lock, sees the owner is gone, and removes the folder with the driver's own half-written
temporaries in OUT (``.<name>.<pid>.partial.<ext>``, ``puppet.atomic``). A live batch's staging
is never touched: its lock is held.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import socket
import tempfile
from pathlib import Path

PREFIX = ".puppet-batch."
SUFFIX = ".partial"
LOCK = ".lock"
_NAME = re.compile(r"^\.puppet-batch\.(?:(?P<host>.+)\.)?(?P<pid>\d+)\.partial$")


def node_temp() -> Path:
    """The system's temporary folder: where Ray tasks on this machine stage."""
    return Path(tempfile.gettempdir())


class Staging:
    """A locked staging folder ``folder/.puppet-batch.<host>.<pid>.partial``, made now.

    ``remove()`` deletes it (and the lock goes with it); safe to call twice."""

    def __init__(self, folder: Path):
        self.path = Path(folder) / f"{PREFIX}{socket.gethostname()}.{os.getpid()}{SUFFIX}"
        self.path.mkdir(parents=True, exist_ok=True)
        self._lock = os.open(self.path / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
        if self._lock is not None:
            os.close(self._lock)  # the lock goes with it
            self._lock = None


def _owner_gone(folder: Path, pid: int, host: str | None) -> bool:
    """True when no live process holds ``folder``'s lock (older staging without a lock file:
    when its pid is not running on this machine)."""
    try:
        fd = os.open(folder / LOCK, os.O_RDWR)
    except FileNotFoundError:
        if host not in (None, socket.gethostname()):
            return False  # another machine's: no way to tell
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            return False
        return pid != os.getpid() and not _is_batch(pid)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False  # held: a batch still runs there
    finally:
        os.close(fd)
    return True


def _is_batch(pid: int) -> bool:
    try:
        return b"puppet" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False


def remove_stale(folder: Path) -> list[Path]:
    """Remove the staging folders (and the drivers' temporaries) that killed batches left in
    ``folder``; returns what was removed."""
    removed: list[Path] = []
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return removed
    for entry in entries:
        match = _NAME.match(entry.name)
        if match is None or not entry.is_dir():
            continue
        pid = int(match["pid"])
        if not _owner_gone(entry, pid, match["host"]):
            continue
        shutil.rmtree(entry, ignore_errors=True)
        removed.append(entry)
        for temporary in entries:  # puppet.atomic's temporaries of that driver
            if temporary.is_file() and re.match(rf"^\..+\.{pid}\.partial(\.[^.]*)?$",
                                                temporary.name):
                temporary.unlink(missing_ok=True)
                removed.append(temporary)
    return removed

