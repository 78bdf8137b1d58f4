"""Character files that are not regular files, or not what their suffix says: a clean error
naming the file, never a hang (a FIFO read would block forever) or numpy's pickle message."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from puppet.rig.errors import RigError
from puppet.rig.load import load_rig


def _rig(folder, mesh: str):
    path = folder / "rig.toml"
    path.write_text(f'name = "x"\nmesh = "{mesh}"\n')
    return path


def test_a_fifo_as_the_mesh_is_refused_without_opening_it(tmp_path):
    os.mkfifo(tmp_path / "mesh.npz")
    # A subprocess: were the FIFO opened, the command would block; the timeout is generous.
    result = subprocess.run([sys.executable, "-P", "-c", "from puppet.cli import main; main()", "rig", "info",
                             str(_rig(tmp_path, "mesh.npz"))],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 1
    assert result.stderr.strip() == (f"Error: {tmp_path / 'mesh.npz'}: is a FIFO (named pipe), "
                                     "not a mesh file (only regular files are read)")


@pytest.mark.parametrize("name", ["mesh.npz", "mesh.glb"])
def test_a_fifo_given_as_the_character_itself_is_refused(tmp_path, name):
    os.mkfifo(tmp_path / name)
    with pytest.raises(RigError) as info:
        load_rig(tmp_path / name)
    assert str(info.value) == (f"{tmp_path / name}: is a FIFO (named pipe), not a character "
                               "file (only regular files are read)")


def test_a_device_as_the_skeleton_is_refused(tmp_path):
    path = tmp_path / "rig.toml"
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    path.write_text('mesh = "m.obj"\nskeleton = "/dev/null"\n')
    with pytest.raises(RigError) as info:
        load_rig(path)
    assert str(info.value) == ("/dev/null: is a device, not a skeleton file (only regular files "
                               "are read)")


def test_a_non_zip_npz_names_the_file(tmp_path):
    (tmp_path / "mesh.npz").write_bytes(b"\x80\x04not a zip at all")
    with pytest.raises(RigError) as info:
        load_rig(_rig(tmp_path, "mesh.npz"))
    assert str(info.value) == (f"{tmp_path / 'mesh.npz'}: not a character .npz: not a zip archive "
                               "(an .npz is written by numpy.savez)")
    assert "pickle" not in str(info.value)


def test_a_fifo_as_the_rig_file_is_refused(tmp_path):
    os.mkfifo(tmp_path / "rig.toml")
    with pytest.raises(RigError) as info:
        load_rig(tmp_path / "rig.toml")
    assert str(info.value) == (f"{tmp_path / 'rig.toml'}: is a FIFO (named pipe), not a rig file "
                               "(only regular files are read)")


@pytest.mark.parametrize("option", ["--rig", "--faults"])
def test_hw_sim_refuses_a_fifo_for_its_files(tmp_path, option):
    os.mkfifo(tmp_path / "fifo")
    result = subprocess.run(["hw-sim", option, str(tmp_path / "fifo")], capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert f"{tmp_path / 'fifo'}: not a regular file (only regular files are read)" in result.stderr
