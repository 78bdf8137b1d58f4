"""The one rule for outputs (``puppet.atomic``), through every command that writes: each output
option pointed at each of the command's inputs, at a FIFO, at a device node and at an existing
file of another kind is refused (exit 1, an Error line naming the file and why) and leaves every
file as it was. hw_sim serves the bus, so a command that wrongly went ahead would write.

Every case runs the command line in this process (click's runner: the same parsing, the same
checks, the same ``Error:`` line and exit status, without a Python start of 3 s per case); a
few cases, one of each reason, run as a ``puppet`` process too, as a user runs them."""

import hashlib
import importlib.util
import os
import shutil
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import hw_sim
from puppet.bus import Reading
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeWriter


def _builtin():
    from puppet.rig import builtin

    return builtin()


MODELS = dict(_builtin().servo_map.models)

#: Why each kind of target is refused: a fragment of the Error line.
REASONS = {"input": "is also an input of this command", "fifo": "FIFO",
           "device": "character device", "kind": "pass --force", "folder": "not a folder"}

# (command, output option, target, why): the targets name files of the `world` fixture;
# "{port}" is hw_sim's port.
BUS_RIG = ["--rig", "{rig}", "--port", "{port}"]
COMMANDS = {
    "calibrate": (["calibrate", *BUS_RIG], ["--out"],
                  {"rig": "input", "npz": "input", "fifo": "fifo", "device": "device",
                   "other_take": "kind"}),
    "calibrate --guided": (["calibrate", *BUS_RIG, "--guided", "--yes"], ["--out"],
                           {"rig": "input", "npz": "input", "calibration": "input",
                            "fifo": "fifo", "device": "device", "other_take": "kind"}),
    "export": (["export", "{take}", "--rig", "{rig}"], ["--gltf", "--usd", "--pc2", "--bvh"],
               {"take": "input", "rig": "input", "npz": "input", "calibration": "input",
                "fifo": "fifo", "device": "device", "other_take": "kind"}),
    "play": (["play", "{take}", "--rig", "{rig}"], ["--out"],
             {"take": "input", "rig": "input", "npz": "input", "calibration": "input",
              "fifo": "fifo", "device": "device", "other_take": "kind"}),
    "play --frames": (["play", "{take}", "--rig", "{rig}"], ["--frames"],
                      {"take": "folder", "rig": "folder", "fifo": "folder", "device": "folder"}),
    "live": (["live", *BUS_RIG, "--seconds", "2"], ["--out", "--record"],
             {"rig": "input", "npz": "input", "calibration": "input", "fifo": "fifo",
              "device": "device"}),
    "live --frames": (["live", *BUS_RIG, "--seconds", "2"], ["--frames"],
                      {"rig": "folder", "fifo": "folder", "device": "folder"}),
    "record": (["record", *BUS_RIG, "--seconds", "2"], ["--out"],
               {"rig": "input", "npz": "input", "calibration": "input", "fifo": "fifo",
                "device": "device"}),
    "demo": (["demo", "--seconds", "1", "--size", "160", "120", "--faults", "{faults}"],
             ["--out"], {"faults": "input", "fifo": "fifo", "device": "device",
                         "other_take": "kind"}),
    "batch": (["batch", "{take}", "--rig", "{rig}", "--formats", "pc2"], ["--out"],
              {"rig": "folder", "fifo": "folder", "device": "folder"}),
    "rig init": (["rig", "init", "{gltf}"], ["--out"],
                 {"gltf": "input", "bin": "input", "fifo": "fifo", "device": "device"}),
    "rig axes": (["rig", "axes", "{rig}"], ["--out"],
                 {"rig": "input", "npz": "input", "calibration": "input", "fifo": "fifo",
                  "device": "device", "other_take": "kind"}),
}
CASES = [pytest.param(name, option, target, why, id=f"{name} {option} {target}")
         for name, (_, options, targets) in COMMANDS.items()
         for option in options for target, why in targets.items()]
#: One case of each reason, run as a `puppet` process as well (the installed entry point).
PROCESS_CASES = [pytest.param(*case, id=f"{case[0]} {case[1]} {case[2]}") for case in (
    ("export", "--pc2", "take", "input"), ("live", "--out", "fifo", "fifo"),
    ("demo", "--out", "device", "device"), ("rig axes", "--out", "other_take", "kind"),
    ("play --frames", "--frames", "rig", "folder"))]


def _take(path: Path) -> Path:
    """A take of the built-in rig's servos: 20 readings."""
    rig = _builtin()
    ids, k = rig.servo_map.ids, len(rig.servo_map)
    with TakeWriter(path, ids=[int(i) for i in ids], models=MODELS, rig_map_text="",
                    calibration_text="", rig_name=rig.name) as writer:
        for i in range(20):
            writer.write(Reading(i * 10_000_000, ids, (rig.servo_map.zero + 10 * i).astype(np.int32),
                                 np.ones(k, bool)))
    return path


@pytest.fixture(scope="module")
def character():
    """The shared skinned glTF test character (``tests/rig/character.py``)."""
    spec = importlib.util.spec_from_file_location(
        "rig_test_character", Path(__file__).parents[1] / "rig" / "character.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def bus():
    with hw_sim.serve(MODELS) as served:
        yield served


@pytest.fixture
def world(tmp_path, character):
    """{name: path} of the files the commands read, and the FIFO and device node, in one
    folder: a copy of the built-in rig with a calibration file, a take, a fault file, a glTF
    character with its buffer in a .bin, and a take that is no input (another kind of file)."""
    shutil.copy(BUILTIN_RIG.with_name("critter.npz"), tmp_path / "critter.npz")
    text = BUILTIN_RIG.read_text()
    (tmp_path / "critter.toml").write_text('calibration = "critter.calibration.toml"\n' + text)
    (tmp_path / "critter.calibration.toml").write_text(
        "# puppet calibration\n[zero_ticks]\n" + "".join(f"{i} = 2048\n" for i in MODELS))
    (tmp_path / "faults.txt").write_text("0.5 drop ids=3 for=0.2\n")
    doc, blob = character.build()
    doc.buffers[0].uri = "beast.bin"
    (tmp_path / "beast.bin").write_bytes(blob)
    doc.save_json(str(tmp_path / "beast.gltf"))
    os.mkfifo(tmp_path / "pipe")
    (tmp_path / "null").symlink_to("/dev/null")  # a device node without root (mknod)
    return {"rig": tmp_path / "critter.toml", "npz": tmp_path / "critter.npz",
            "calibration": tmp_path / "critter.calibration.toml",
            "take": _take(tmp_path / "take.mcap"), "faults": tmp_path / "faults.txt",
            "gltf": tmp_path / "beast.gltf", "bin": tmp_path / "beast.bin",
            "other_take": _take(tmp_path / "other.mcap"), "fifo": tmp_path / "pipe",
            "device": tmp_path / "null"}


def _state(folder: Path) -> dict:
    """Every entry of the folder: a regular file's SHA-256, else its kind (and link target)."""
    state = {}
    for path in sorted(folder.iterdir()):
        mode = os.lstat(path).st_mode
        if stat.S_ISREG(mode):
            state[path.name] = hashlib.sha256(path.read_bytes()).hexdigest()
        elif stat.S_ISLNK(mode):
            state[path.name] = ("link", os.readlink(path), stat.S_ISCHR(os.stat(path).st_mode))
        else:
            state[path.name] = stat.filemode(mode)
    return state


def _command(name: str, option: str, target: str, world: dict, bus) -> list[str]:
    args, _, _ = COMMANDS[name]
    fields = {key: str(path) for key, path in world.items()} | {"port": bus.port}
    return [arg.format(**fields) for arg in args] + [option, str(world[target])]


def _assert_refused(returncode: int, stderr: str, target: Path, why: str) -> None:
    """Exit 1 and one Error line naming the target and the reason; no traceback."""
    assert returncode == 1, (returncode, stderr)
    assert "Traceback" not in stderr, stderr
    errors = [line for line in stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1, stderr
    assert str(target) in errors[0], errors[0]
    assert REASONS[why] in errors[0], errors[0]


@pytest.mark.parametrize("name, option, target, why", CASES)
def test_an_output_on_an_input_a_device_or_another_kind_is_refused(name, option, target, why,
                                                                     world, bus, tmp_path):
    from puppet.cli import main

    command = _command(name, option, target, world, bus)
    before = _state(tmp_path)
    result = CliRunner().invoke(main, command, prog_name="puppet")
    # an exception that escaped the command line (not its exit) is a traceback for a user
    assert isinstance(result.exception, SystemExit), result.exc_info
    _assert_refused(result.exit_code, result.stderr, world[target], why)
    assert _state(tmp_path) == before
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


@pytest.mark.parametrize("name, option, target, why", PROCESS_CASES)
def test_the_puppet_command_refuses_an_output_on_an_input_or_a_node(name, option, target, why,
                                                                    world, bus, tmp_path):
    command = _command(name, option, target, world, bus)
    before = _state(tmp_path)
    result = subprocess.run(["puppet", *command], capture_output=True, text=True, timeout=300)
    _assert_refused(result.returncode, result.stderr, world[target], why)
    assert _state(tmp_path) == before
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_force_replaces_another_kind_but_never_an_input(world, tmp_path):
    """--force lets an export replace an unrelated file of another kind; an input stays refused."""
    other = world["other_take"]
    result = subprocess.run(["puppet", "export", str(world["take"]), "--rig", str(world["rig"]),
                             "--pc2", str(other), "--force"], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    assert other.read_bytes()[:12] == b"POINTCACHE2\0"
    before = _state(tmp_path)
    result = subprocess.run(["puppet", "export", str(world["take"]), "--rig", str(world["rig"]),
                             "--pc2", str(world["npz"]), "--force"], capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 1, result.stderr
    assert REASONS["input"] in result.stderr
    assert _state(tmp_path) == before


def test_a_hard_link_to_an_input_is_the_input(world, tmp_path):
    """Compared by device and inode too: a hard link to the rig file is refused as the rig file."""
    link = tmp_path / "alias.pc2"
    os.link(world["rig"], link)
    before = _state(tmp_path)
    result = subprocess.run(["puppet", "export", str(world["take"]), "--rig", str(world["rig"]),
                             "--pc2", str(link)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 1, result.stderr
    assert str(link) in result.stderr and REASONS["input"] in result.stderr
    assert _state(tmp_path) == before
