"""sha256 content keys of files and of bytes.

Batch manifests key a take's outputs on them (``puppet.batch.manifest``). The character a rig
solves has its own (``puppet.rig.checksum.character_sha256``).
"""

from __future__ import annotations

import hashlib
import os

_CHUNK = 1 << 20


def file_sha256(path: str | os.PathLike) -> str:
    """sha256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def bytes_sha256(data: bytes | str) -> str:
    """sha256 (hex) of bytes (a str as UTF-8)."""
    return hashlib.sha256(data.encode("utf-8") if isinstance(data, str) else data).hexdigest()
