"""The on-disk cache shared by every part: one root folder, one environment variable.

Root: ``$PUPPET_CACHE``, else ``$XDG_CACHE_HOME/puppet``, else ``~/.cache/puppet``. A part keeps
its entries in the root (``cache_root()``) or a sub-folder of it (``cache_dir("fast")``).

A cache only saves time: an entry that cannot be read or written (read-only folder, full disk,
a truncated file) is logged on the ``puppet.cache`` logger and the work is done again.
``code_digest`` gives a key part that changes with the code that produced an entry, so an
edited package never reuses stale results.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
from collections.abc import Callable
from pathlib import Path

ENV = "PUPPET_CACHE"
"""The environment variable naming the cache root."""

log = logging.getLogger(__name__)


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
