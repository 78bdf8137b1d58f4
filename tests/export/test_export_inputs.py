"""No export writes over a file it reads, also when the rig is the one the take stores (no
--rig): ``puppet.replay.take_inputs`` lists every file replaying a take reads (the take, the
character the take's rig map names, its buffer and image, the calibration file), checked here
against the files loading actually opens; then each is tried as each export's output, in
process, and once through the CLI (the case of the issue: ``--gltf CHARACTER.glb``)."""

import hashlib
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from puppet.atomic import OutputError
from puppet.bus import Reading
from puppet.export import Outputs, export_take
from puppet.replay import open_take, take_inputs
from puppet.take import TakeWriter


def _character_module():
    spec = importlib.util.spec_from_file_location(
        "rig_test_character", Path(__file__).parents[1] / "rig" / "character.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


character = _character_module()
FORMATS = ("gltf", "usd", "pc2", "bvh")


def _record(rig, path: Path) -> Path:
    """A take of ``rig`` written as ``puppet record`` writes one (its rig map and where it was)."""
    from puppet.take.header import take_header

    ids, k = rig.servo_map.ids, len(rig.servo_map)
    with TakeWriter(path, **take_header(rig)) as writer:
        for i in range(12):
            writer.write(Reading(i * 33_000_000, ids, (rig.servo_map.zero + 20 * i).astype(np.int32),
                                 np.ones(k, bool)))
    return path


def _world(folder: Path, suffix: str) -> dict[str, Path]:
    """The mare as a .gltf (buffer in mare.bin, texture coat.png) or a .glb, its rig file with a
    calibration file, and a take recorded on it: {role: path}."""
    from puppet.rig import load_rig

    mare = character.mare()
    files = {"character": folder / f"mare{suffix}"}
    if suffix == ".gltf":
        doc, blob = character.document(mare, binary=False)
        doc.buffers[0].uri = "mare.bin"
        files["buffer"] = folder / "mare.bin"
        files["buffer"].write_bytes(blob)
        files["texture"] = folder / mare.image[1]
        files["texture"].write_bytes(character.png_bytes())
        doc.save_json(str(files["character"]))
    else:
        character.write(files["character"], mare)
    files["calibration"] = folder / "mare.calibration.toml"
    files["calibration"].write_text("# puppet calibration\n[zero_ticks]\n"
                                    + "".join(f"{i} = 2000\n" for i, _ in
                                              character.MARE_SERVOS.values()))
    files["rig"] = folder / "mare.toml"
    files["rig"].write_text('calibration = "mare.calibration.toml"\n'
                            + character.mare_rig_text(files["character"].name))
    files["take"] = _record(load_rig(files["rig"]), folder / "take.mcap")
    return files


def _digest(paths) -> dict:
    return {path: hashlib.sha256(path.read_bytes()).hexdigest() for path in paths}


@pytest.fixture(scope="module")
def gltf_world(tmp_path_factory):
    return _world(tmp_path_factory.mktemp("gltf_world"), ".gltf")


def test_take_inputs_hold_every_file_replaying_the_take_opens(gltf_world):
    folder = gltf_world["take"].parent
    opened: list[Path] = []
    watching = [True]

    def hook(event, args):
        if watching[0] and event == "open" and isinstance(args[0], (str, bytes, Path)):
            path = Path(args[0] if not isinstance(args[0], bytes) else args[0].decode())
            if path.resolve().parent == folder.resolve():
                opened.append(path.resolve())

    sys.addaudithook(hook)  # a hook cannot be removed: it stops listening below
    try:
        rig, reader = open_take(gltf_world["take"], None)
        inputs = take_inputs(reader.path, rig)
    finally:
        watching[0] = False
    listed = {Path(p).resolve() for p in inputs}
    assert set(opened) <= listed, f"opened but not listed: {set(opened) - listed}"
    # what the take's rig map names, also a file it names that loading needs not open
    for role in ("take", "character", "buffer", "texture", "calibration"):
        assert gltf_world[role].resolve() in listed, role


@pytest.mark.parametrize("fmt", FORMATS)
def test_no_export_replaces_a_file_of_the_takes_own_rig(fmt, gltf_world):
    rig, reader = open_take(gltf_world["take"], None)  # no --rig: the rig the take stores
    roles = ("take", "character", "buffer", "texture", "calibration")
    before = _digest(gltf_world[role] for role in roles)
    for role in roles:
        with pytest.raises(OutputError, match="is also an input of this command"):
            export_take(rig, reader, Outputs(**{fmt: gltf_world[role]}, force=True))
    assert _digest(gltf_world[role] for role in roles) == before


def test_batch_refuses_an_output_on_the_character_of_a_takes_own_rig(tmp_path):
    """``puppet batch`` without --rig, outputs beside the character: take mare.mcap would write
    mare.glb over its own character; the take fails before any work, naming the file."""
    from puppet.batch import run_batch

    world = _world(tmp_path, ".glb")
    take = world["take"].rename(tmp_path / "mare.mcap")
    before = _digest([world["character"]])
    report = run_batch([str(take)], tmp_path, formats=("gltf",), engine="local", workers=1)
    row, = report.rows
    assert row.state == "failed"
    assert "is also an input of this command" in row.reason and "mare.glb" in row.reason
    assert _digest([world["character"]]) == before


def test_cli_export_without_rig_refuses_the_character_as_gltf_output(tmp_path):
    world = _world(tmp_path, ".glb")
    before = _digest(world.values())
    result = subprocess.run(["puppet", "export", str(world["take"]),
                             "--gltf", str(world["character"])], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 1, result.stderr
    assert "Error:" in result.stderr and "is also an input of this command" in result.stderr
    assert "Traceback" not in result.stderr
    assert _digest(world.values()) == before
