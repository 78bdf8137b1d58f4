"""Errors say what is wrong: a missing .npz is "not found" (not "not a zip archive"); a shot cut
short says so (not "not a shot"); shots and the add-on are refused under another suffix;
``hw-sim --servos ''`` serves nothing rather than 14 servos; a text file given as a texture is
left out with a warning naming it; a file where the textures folder goes is named."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from puppet.atomic import OutputError
from puppet.rig import RigError
from puppet.rig.load import read_character_npz
from puppet.take import TakeError


def _character_module():
    spec = importlib.util.spec_from_file_location(
        "rig_test_character", Path(__file__).parents[1] / "rig" / "character.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_missing_npz_is_not_found(tmp_path):
    with pytest.raises(RigError) as err:
        read_character_npz(tmp_path / "gone.npz")
    assert str(err.value) == f"{tmp_path / 'gone.npz'}: character file not found"


def _shot(path):
    from puppet.keys import write_shot
    from puppet.keys.example import critter_keys
    from puppet.rig import builtin

    rig = builtin()
    header = {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
              "rig_map_text": "", "calibration_text": "", "rig_name": rig.name}
    write_shot(path, header, critter_keys(rig))
    return path


def test_a_shot_cut_before_its_keys_says_it_is_cut_short(tmp_path):
    from puppet.keys import read_shot

    shot = _shot(tmp_path / "shot.mcap")
    data = shot.read_bytes()
    shot.write_bytes(data[:data.find(b"/puppet/keys") - 40])  # cut inside the keys' records
    with pytest.raises(TakeError) as err:
        read_shot(shot)
    assert "no keys: the file is cut short" in str(err.value)
    assert "not a shot" not in str(err.value)


def test_a_shot_and_the_add_on_are_refused_under_another_suffix(tmp_path):
    from puppet.keys.shot import check_shot_path
    from puppet.link.addon import write_addon

    with pytest.raises(TakeError, match=r"a shot is a take: name it \*\.mcap"):
        check_shot_path(tmp_path / "shot.glb")
    assert check_shot_path(tmp_path / "shot.MCAP").name == "shot.MCAP"
    with pytest.raises(OutputError, match=r"name it \*\.zip"):
        write_addon(tmp_path / "addon.glb")
    assert not (tmp_path / "addon.glb").exists()
    result = subprocess.run(["puppet", "keys", "retime", str(_shot(tmp_path / "s.mcap")), "0=2",
                             "--out", str(tmp_path / "retimed.pc2")], capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 1 and "name it *.mcap" in result.stderr
    assert not (tmp_path / "retimed.pc2").exists()


def test_hw_sim_with_no_servo_ids_serves_nothing(tmp_path):
    result = subprocess.run([sys.executable, "-m", "hw_sim.cli", "--servos", ""],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0
    assert "no servo ids given" in result.stderr


@pytest.fixture
def textured(tmp_path):
    """The mare as a .gltf whose texture is coat.png next to it, and its rig file."""
    character = _character_module()
    mare = character.mare()
    gltf = character.write(tmp_path / "mare.gltf", mare)
    (tmp_path / "mare.toml").write_text(character.mare_rig_text(gltf.name))
    return tmp_path / "mare.toml", tmp_path / mare.image[1]


def _export_usd(rig_path, out):
    import numpy as np

    from puppet.bus import Reading
    from puppet.export import Outputs, export_take
    from puppet.replay import open_take
    from puppet.rig import load_rig
    from puppet.take import TakeWriter

    rig = load_rig(rig_path)
    ids, k = rig.servo_map.ids, len(rig.servo_map)
    take = out.parent / "take.mcap"
    with TakeWriter(take, ids=[int(i) for i in ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name,
                    overwrite=True) as writer:
        for i in range(3):
            writer.write(Reading(i * 33_000_000, ids, rig.servo_map.zero.astype(np.int32),
                                 np.ones(k, bool)))
    rig, reader = open_take(take, rig)
    return export_take(rig, reader, Outputs(usd=out), fps=30)


def test_a_text_file_as_a_texture_is_left_out_with_a_warning(textured, tmp_path):
    gltf, image = textured
    image.write_text("this is not a png")  # 17 bytes of text
    report = _export_usd(gltf, tmp_path / "mare.usda")
    assert any(str(image) in w and "not a PNG or JPEG image (17 bytes" in w
               for w in report.warnings), report.warnings
    assert not (tmp_path / "mare_textures").exists()  # nothing to package


def test_a_file_where_the_textures_folder_goes_is_named(textured, tmp_path):
    gltf, _ = textured
    (tmp_path / "mare_textures").write_text("in the way")
    with pytest.raises(OutputError) as err:
        _export_usd(gltf, tmp_path / "mare.usda")
    assert f"{tmp_path / 'mare_textures'}: exists and is a file, not a folder" in str(err.value)
    assert not (tmp_path / "mare.usda").exists()
