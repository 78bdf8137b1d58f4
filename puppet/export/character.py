"""The character alone, at rest, as a glTF binary: its mesh, its skin and every joint (one key,
the rest pose), in the character file's vertex order: what Blender's glTF importer makes the
armature and mesh of that the live link's add-on drives (``puppet blender character``).

It is ``puppet export --gltf``'s own writer (``GltfWriter``) given one frame in which every
joint's rigid map is the identity, so the armature, the joint names and the vertex order are
those of every export of the rig's takes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from puppet.atomic import atomic_output
from puppet.export.errors import ExportError
from puppet.export.gltf import GltfWriter
from puppet.export.source_order import SourceOrder


def write_character(rig, out, *, inputs=(), force: bool = False) -> Path:
    """Write ``rig``'s character at rest to ``out`` (.glb; the one rule for outputs:
    ``puppet.atomic``; inputs: files it was read from, never written over). Returns the path.
    ExportError naming ``out`` for another suffix (Blender's importer goes by the name)."""
    if Path(out).suffix.lower() != ".glb":
        raise ExportError(out, "the character is a glTF binary: name it *.glb (e.g. critter.glb)")
    sk = rig.skeleton
    order = SourceOrder(rig)
    with atomic_output(out, kind="glb", inputs=inputs, force=force,
                       what="character") as temporary:
        writer = GltfWriter(temporary, names=sk.names, parents=sk.parents, heads=sk.heads,
                            frames=sk.frames, V=order.take(rig.V), F=order.F,
                            W=order.take(rig.W), fps=30.0, name=rig.name, source=rig.source)
        rest = np.zeros((len(sk.names), 3, 4))
        rest[:, :, :3] = np.eye(3)
        writer.write(rest)
        writer.close()
    return Path(out)
