"""The one rule for outputs, and outputs that are whole or absent.

Every command that writes a file checks it here first (``check_output``), before it touches
anything: an output may not be one of the command's inputs (the same resolved path, or the same
device and inode: a hard link or a symbolic link), may not be an existing non-regular file (a
device node, a FIFO, a folder), and may replace an existing file only when that file is of the
kind the command writes (sniffed from its content: a take where a PC2 goes is refused), unless
the user passed ``--force``. Takes and new rig files (``keep_existing``) never replace an existing
file without ``--force``. Inputs and non-regular files are refused even with ``--force``.

Outputs other than a take are then written through ``atomic_output``: a temporary file next to
the target, renamed into place when whole; a failed or interrupted write leaves no half file and
never replaces an existing good one.
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

from puppet.errors import PuppetError


class OutputError(PuppetError):
    """An output path cannot be used: it is an input, not a regular file, of another kind, exists
    without --force, or its folder is missing or unwritable."""


#: What each kind of file is called in a refusal.
KIND_NAMES = {
    "take": "a take (MCAP)", "video": "a video", "png": "a PNG image", "glb": "a glTF binary",
    "gltf": "a glTF character (JSON)", "usd": "a USD file", "pc2": "a PC2 point cache",
    "bvh": "a BVH file", "npz": "a zip archive (.npz character)", "mesh": "a mesh (OBJ/PLY)",
    "calibration": "a calibration file", "rig file": "a rig file", "text": "a text file",
    "data": "a file of unknown content",
}

_RIG_KEYS = re.compile(rb"^\s*(mesh\s*=|\[\[servo\]\]|\[\[pin\]\]|\[solver\])", re.MULTILINE)
_CALIBRATION = re.compile(rb"^\s*\[zero_ticks\]|\"zero_ticks\"\s*:", re.MULTILINE)


def file_kind(path: str | os.PathLike) -> str:
    """What an existing regular file holds, from its first bytes: a key of KIND_NAMES, or
    "empty"."""
    with open(path, "rb") as handle:
        head = handle.read(4096)
    if not head:
        return "empty"
    magics = ((b"\x89MCAP0\r\n", "take"), (b"glTF", "glb"), (b"\x89PNG\r\n\x1a\n", "png"),
              (b"POINTCACHE2\0", "pc2"), (b"PXR-USDC", "usd"), (b"#usda", "usd"),
              (b"HIERARCHY", "bvh"), (b"PK\x03\x04", "npz"), (b"\x1aE\xdf\xa3", "video"),
              (b"ply\n", "mesh"), (b"ply\r\n", "mesh"))
    if head.startswith(b"PK\x03\x04") and len(head) >= 30:  # a .usdz: a zip whose first file is a layer
        name_length = int.from_bytes(head[26:28], "little")
        if head[30:30 + name_length].lower().endswith((b".usdc", b".usda", b".usd")):
            return "usd"
    for magic, kind in magics:
        if head.startswith(magic):
            return kind
    if head[4:8] == b"ftyp" or (head[:4] == b"RIFF" and head[8:12] == b"AVI "):
        return "video"
    if b"\0" in head:
        return "data"
    if _RIG_KEYS.search(head):
        return "rig file"
    if _CALIBRATION.search(head):
        return "calibration"
    if head.lstrip().startswith(b"{") and b'"asset"' in head:
        return "gltf"
    if re.search(rb"^v\s+-?[\d.]", head, re.MULTILINE):
        return "mesh"
    return "text"


def node_kind(mode: int) -> str | None:
    """A non-regular file's kind in words; None for a regular file."""
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return None if stat.S_ISREG(mode) else "not a regular file"


def _same_file(a: Path, b: Path) -> bool:
    """True when a and b name one file: equal resolved paths, or equal (device, inode)."""
    if a.resolve() == b.resolve():
        return True
    try:
        sa, sb = os.stat(a), os.stat(b)
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def check_output(target: str | os.PathLike, *, kind: str, inputs: Iterable = (),
                 force: bool = False, keep_existing: bool = False, what: str = "output") -> Path:
    """The output path, or OutputError naming it and why (see the module's rule).

    kind:          what the command writes there (a key of KIND_NAMES).
    inputs:        files the command reads (None entries are skipped); the output may be none.
    force:         the user passed --force: an existing file of another kind may be replaced.
    keep_existing: any existing file needs --force (takes, new rig files).
    what:          the output's role in messages ("video", "take", "--pc2 output").
    """
    path = Path(target)
    for source in inputs:
        if source is not None and _same_file(path, Path(source)):
            same = "" if str(source) == str(path) else f" ({source})"
            raise OutputError(f"{path}: the {what} is also an input of this command{same}; "
                              "choose another path")
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as err:
        raise OutputError(f"{path}: cannot use it as the {what}: {err.strerror or err}") from None
    if mode is not None:
        node = node_kind(mode)
        if node is not None:
            raise OutputError(f"{path}: exists and is {node}, not a regular file; the {what} "
                              "must be a file path")
        found = file_kind(path)
        if keep_existing and not force:
            raise OutputError(f"{path}: exists; pass --force to overwrite it (it is "
                              f"{KIND_NAMES.get(found, found)})")
        if found not in ("empty", kind) and not force:
            raise OutputError(f"{path}: exists and is {KIND_NAMES.get(found, found)}, not "
                              f"{KIND_NAMES[kind]}; pass --force to overwrite it")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"{path}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise OutputError(f"{path}: folder {folder} is not writable")
    return path


def check_folder_output(folder: str | os.PathLike, *, what: str = "frame folder") -> Path:
    """An output folder (PNG frames): refused when it exists and is not a folder."""
    path = Path(folder)
    try:
        mode = os.stat(path).st_mode
    except OSError:  # absent (or a file on its way): making it says what is wrong
        return path
    if not stat.S_ISDIR(mode):
        raise OutputError(f"{path}: exists and is {node_kind(mode) or 'a file'}, not a folder; "
                          f"the {what} must be a folder path")
    return path


def check_distinct(outputs: Mapping[str, str | os.PathLike | None]) -> None:
    """Refuse two output options naming one file: {option: path} (None entries skipped)."""
    seen: list[tuple[str, Path]] = []
    for option, target in outputs.items():
        if target is None:
            continue
        for other, path in seen:
            if _same_file(Path(target), path):
                raise OutputError(f"{target}: given for both {other} and {option}")
        seen.append((option, Path(target)))


def temporary_sibling(target: str | os.PathLike) -> Path:
    """A hidden temporary path in the target's folder (same file system, so a rename is atomic);
    it keeps the target's suffix so that writers choosing a format by suffix still work."""
    path = Path(target)
    return path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")


def flush(path: str | os.PathLike) -> None:
    """Flush a written file's data to disk."""
    handle = os.open(path, os.O_RDONLY)
    try:
        os.fsync(handle)
    finally:
        os.close(handle)


def commit(temporary: str | os.PathLike, target: str | os.PathLike) -> None:
    """Flush the finished temporary file to disk and rename it over the target."""
    flush(temporary)
    os.replace(temporary, target)


@contextmanager
def atomic_output(target: str | os.PathLike, *, kind: str, inputs: Iterable = (),
                  force: bool = False, keep_existing: bool = False,
                  what: str = "output") -> Iterator[Path]:
    """Yield a temporary path to write; rename it to ``target`` when the block ends normally.

    The target is checked first (``check_output``, same arguments). On an exception (or
    Ctrl-C) the temporary file is removed and the target is untouched.
    """
    path = check_output(target, kind=kind, inputs=inputs, force=force,
                        keep_existing=keep_existing, what=what)
    temporary = temporary_sibling(path)
    try:
        yield temporary
        commit(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
