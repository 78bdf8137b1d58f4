"""The checksum of the character a rig solves (``character_sha256``).

A take records its character's (``puppet.replay.RIG_CHARACTER_MARK``) so the rig it is replayed
on is the one it was recorded on; batch manifests key a take's outputs on it
(``puppet.batch.manifest``).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from puppet.checksum import file_sha256


def character_sha256(rig) -> str:
    """sha256 (hex) of the character a rig solves, as loaded: rest vertices, triangles, weights,
    the skeleton (names, parents, heads, tails, frames) and the source vertex order; for a glTF
    character, also the bytes of its file and of the buffers and images it names (its look and
    place, which exports carry: ``Rig.source``). The same character gives the same checksum
    whichever folder it was read from."""
    from puppet.rig.gltf import external_files

    h = hashlib.sha256()
    source = getattr(rig, "source", None)
    if source is not None:
        for path in [Path(source.path), *external_files(source.path)]:
            h.update(file_sha256(path).encode() if path.is_file() else b"missing")
    skeleton = rig.skeleton
    arrays = [rig.V, rig.F, rig.W, skeleton.parents, skeleton.heads, skeleton.tails,
              skeleton.frames, rig.source_index if rig.source_index is not None else np.zeros(0)]
    for array in arrays:
        array = np.ascontiguousarray(array)
        h.update(f"{array.dtype.str}{array.shape}".encode())
        h.update(array.tobytes())
    h.update("\0".join(skeleton.names).encode("utf-8"))
    return h.hexdigest()
