"""``puppet blender character --out`` writes a glTF binary: a name Blender's importer would not
take as one (c.txt) is refused before anything is written, as export's --gltf is."""

import pytest

from puppet.export.character import write_character
from puppet.export.errors import ExportError
from puppet.rig import builtin


def test_the_character_must_be_named_glb(tmp_path):
    rig = builtin()
    for name in ("c.txt", "c.gltf", "c"):
        with pytest.raises(ExportError, match=r"the character is a glTF binary: name it \*\.glb"):
            write_character(rig, tmp_path / name)
        assert not (tmp_path / name).exists()
    assert write_character(rig, tmp_path / "c.GLB").stat().st_size > 1000
