"""The on-disk cache shared by every part: one root folder, one environment variable.

Root: ``$PUPPET_CACHE``, else ``$XDG_CACHE_HOME/puppet``, else ``~/.cache/puppet``. A part keeps
its entries in the root (``cache_root()``) or a sub-folder of it (``cache_dir("fast")``).

One entry mechanism for every part (``Entry``): a file ``<folder>/<prefix>-<key><suffix>``
whose key hashes the digest of the code that computes it (``code_digest``: an edited package
never reuses stale results) and every input, read with a check and written whole.

A cache only saves time: an entry that cannot be read or written (read-only folder, full disk,
a truncated file) is logged on the ``puppet.cache`` logger and the work is done again.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

ENV = "PUPPET_CACHE"
"""The environment variable naming the cache root."""

log = logging.getLogger(__name__)

T = TypeVar("T")

BAD_ENTRY = (OSError, ValueError, KeyError, EOFError)
"""What reading a damaged entry raises (and what a ``load`` check raises to refuse one)."""


def cache_root() -> Path:
    """$PUPPET_CACHE, else $XDG_CACHE_HOME/puppet, else ~/.cache/puppet."""
    if os.environ.get(ENV):
        return Path(os.environ[ENV])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "puppet"


def cache_dir(part: str) -> Path:
    """The folder of one part's entries, e.g. cache_dir('fast') -> <root>/fast."""
    return cache_root() / part


@functools.lru_cache(maxsize=None)
def code_digest(*paths: str) -> str:
    """sha256 (hex) of the files at ``paths`` and of every ``.py`` file under each folder
    among them (relative names and bytes, sorted): it changes when any of that code does."""
    h = hashlib.sha256()
    for root in map(Path, paths):
        files = sorted(root.rglob("*.py")) if root.is_dir() else [root]
        for file in files:
            h.update(str(file.relative_to(root.parent)).encode())
            h.update(file.read_bytes())
    return h.hexdigest()


def read_failed(path: Path, err: Exception) -> None:
    """Log a cache entry that could not be read (it is recomputed and rewritten)."""
    log.warning("cache entry %s unreadable (%s: %s); recomputing", path, type(err).__name__, err)


def write_failed(path: Path, err: Exception) -> None:
    """Log a cache entry that could not be written (the next run recomputes it)."""
    log.warning("cache entry %s not written (%s: %s)", path, type(err).__name__, err)


def store(path: Path, write: Callable[[Path], None]) -> None:
    """Write a cache entry: ``write(temporary)`` fills a sibling of ``path`` (same suffix), which
    is then renamed to ``path``, so a reader never sees half an entry. A folder or disk that
    refuses is logged (``write_failed``) and the entry skipped."""
    temporary = path.with_name(f"{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(temporary)
        os.replace(temporary, path)
    except OSError as err:
        write_failed(path, err)
        with contextlib.suppress(OSError):
            temporary.unlink(missing_ok=True)


def entry_key(code: str, *parts) -> str:
    """sha256 (hex, 32 characters) of ``code`` (a ``code_digest``, or one of several joined)
    and ``parts``, each an array (its dtype, shape and bytes) or a value (its ``repr``)."""
    h = hashlib.sha256(code.encode())
    for part in parts:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"|{a.dtype.str}{a.shape}|".encode())
            h.update(a.tobytes())
        else:
            h.update(f"|{part!r}|".encode())
    return h.hexdigest()[:32]


@dataclass(frozen=True)
class Entry:
    """One cache entry: the file ``path`` (see ``Entry.keyed``)."""

    path: Path

    @classmethod
    def keyed(cls, folder: Path, prefix: str, suffix: str, code: str, *parts) -> "Entry":
        """The entry in ``folder`` for the code with digest ``code`` given ``parts`` (its inputs
        and settings: ``entry_key``), named ``<prefix>-<key><suffix>``."""
        return cls(Path(folder) / f"{prefix}-{entry_key(code, *parts)}{suffix}")

    def load(self, read: Callable[[Path], T]) -> T | None:
        """``read(path)`` -> the stored value, or None: no entry yet, or one ``read`` refused
        (it raises one of ``BAD_ENTRY``, e.g. ValueError from its own check of the value),
        logged (``read_failed``) and recomputed by the caller."""
        if not self.path.exists():
            return None
        try:
            return read(self.path)
        except BAD_ENTRY as err:
            read_failed(self.path, err)
            return None

    def store(self, write: Callable[[Path], None]) -> None:
        """Write the entry whole (``store``); a refusal is logged, not raised."""
        store(self.path, write)
