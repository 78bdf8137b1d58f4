"""Outputs that are whole or absent: written to a temporary file next to the target, then renamed.

Every output other than a take (videos, point caches, exports, rig files written by a command)
goes through ``atomic_output``: a failed or interrupted write leaves no half file and never
replaces an existing good one. ``check_output`` refuses an output that is one of the command's
inputs, or an existing file when overwriting was not asked for.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from puppet.errors import PuppetError


class OutputError(PuppetError):
    """An output path cannot be used: it is an input, exists without --force, or is unwritable."""


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output(target: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (),
                 overwrite: bool = True, what: str = "output") -> Path:
    """The output path, after refusing an input given as output or (without overwrite) an existing file.

    target:    the output file.
    inputs:    files the command reads; the output may be none of them.
    overwrite: False to refuse an existing target (the message names ``--force``).
    """
    path = Path(target)
    for source in inputs:
        source_path = Path(source)
        if path.resolve() == source_path.resolve() or _same_file(path, source_path):
            raise OutputError(f"{path}: the {what} is also an input of this command; "
                              "choose another path")
    if not overwrite and path.exists():
        raise OutputError(f"{path}: exists; pass --force to overwrite it")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"{path}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise OutputError(f"{path}: folder {folder} is not writable")
    return path


def temporary_sibling(target: str | os.PathLike) -> Path:
    """A hidden temporary path in the target's folder (same file system, so a rename is atomic);
    it keeps the target's suffix so that writers choosing a format by suffix still work."""
    path = Path(target)
    return path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")


def commit(temporary: str | os.PathLike, target: str | os.PathLike) -> None:
    """Flush the finished temporary file to disk and rename it over the target."""
    with open(temporary, "rb+") as handle:
        os.fsync(handle.fileno())
    os.replace(temporary, target)


@contextmanager
def atomic_output(target: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (),
                  overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary path to write; rename it to ``target`` when the block ends normally.

    On an exception (or Ctrl-C) the temporary file is removed and the target is untouched.
    """
    path = check_output(target, inputs=inputs, overwrite=overwrite)
    temporary = temporary_sibling(path)
    try:
        yield temporary
        commit(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
