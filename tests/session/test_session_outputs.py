"""A session checks every output before anything starts, and names the output that cannot be
made: the port given here does not exist, so an error about the output (not the port) proves
the bus was never touched."""

from __future__ import annotations

import socket
import stat

import pytest
from click.testing import CliRunner

from puppet.cli import main
from puppet.rig.load import BUILTIN_RIG

NO_PORT = "/dev/puppet-no-such-port"


def _live(*args: str):
    return CliRunner().invoke(main, ["live", "--rig", str(BUILTIN_RIG), "--port", NO_PORT, *args])


@pytest.fixture
def read_only(tmp_path):
    """A folder no output can be written into: read-only by its mode, or (as root, who writes
    anywhere) a read-only tmpfs mounted there."""
    import os
    import subprocess

    folder = tmp_path / "ro"
    folder.mkdir()
    if os.geteuid() != 0:
        folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
        yield folder
        folder.chmod(stat.S_IRWXU)
        return
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(folder)],
                             capture_output=True, text=True, timeout=60)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a read-only tmpfs here: {mounted.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=True, timeout=60)


@pytest.mark.parametrize("option, name", [("--out", "v.mp4"), ("--record", "t.mcap"),
                                          ("--frames", "frames")])
def test_an_output_in_a_read_only_folder_fails_before_the_bus(option, name, read_only):
    result = _live(option, str(read_only / name))
    assert result.exit_code == 1, result.output
    assert str(read_only / name) in result.output, result.output
    assert "not writable" in result.output, result.output
    assert NO_PORT not in result.output


def test_a_missing_folder_is_named_before_the_bus(tmp_path):
    result = _live("--out", str(tmp_path / "nowhere" / "v.mp4"))
    assert result.exit_code == 1, result.output
    assert f"{tmp_path / 'nowhere'}" in result.output and "does not exist" in result.output
    assert NO_PORT not in result.output


@pytest.mark.parametrize("option", ["--view", "--link"])
def test_a_taken_address_fails_before_the_bus_naming_the_option(option):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = _live(option, f"127.0.0.1:{port}")
    assert result.exit_code == 1, result.output
    assert f"{option}: address 127.0.0.1:{port} is already in use" in result.output, result.output
    assert NO_PORT not in result.output


def test_view_and_link_on_one_address_are_refused_naming_both():
    result = _live("--view", "127.0.0.1:9333", "--link", "127.0.0.1:9333")
    assert result.exit_code == 1, result.output
    assert "--view 127.0.0.1:9333 and --link 127.0.0.1:9333 name one address" in result.output
    assert NO_PORT not in result.output


@pytest.mark.parametrize("view, link", [("0.0.0.0:9333", "127.0.0.1:9333"),
                                        ("localhost:9333", "127.0.0.1:9333"),
                                        ("9100", "")])  # the link's default port
def test_view_and_link_that_would_share_a_port_are_refused_naming_both(view, link):
    """Two spellings of one place (a name and its address, the wildcard and any address) are one
    address too: refused naming both options, not 'already in use, stop the other program'."""
    result = _live("--view", view, "--link", link)
    assert result.exit_code == 1, result.output
    assert f"--view {view} and --link" in result.output and "name one address" in result.output, \
        result.output
    assert "already in use" not in result.output and NO_PORT not in result.output


def test_view_and_link_on_one_port_of_two_hosts_both_listen():
    from puppet.net.address import one_place

    assert not one_place(("127.0.0.1", 9333), ("127.0.0.2", 9333))
    assert not one_place(("127.0.0.1", 0), ("127.0.0.1", 0))
    assert one_place(("::", 9333), ("127.0.0.1", 9333))


def test_an_input_given_as_an_output_is_refused_before_the_bus():
    result = _live("--out", str(BUILTIN_RIG))
    assert result.exit_code == 1, result.output
    assert str(BUILTIN_RIG) in result.output and NO_PORT not in result.output, result.output


def test_two_outputs_on_one_file_are_refused(tmp_path):
    same = str(tmp_path / "x.mcap")
    result = _live("--record", same, "--out", same)
    assert result.exit_code == 1, result.output
    assert "given for both --record and --out" in result.output, result.output


def test_a_video_that_made_nothing_leaves_no_file_and_one_that_made_a_frame_keeps_it(tmp_path):
    """The stop rule for a frame sink (``puppet.session.outputs.close_sink``), as every video
    output and the benchmarks' demo sinks (``puppet.demo.run_demo``) close by it."""
    import imageio_ffmpeg
    import numpy as np

    from puppet.session.outputs import Video

    said: list = []
    empty = Video(tmp_path / "empty.mp4", 30.0, tell=said.append)
    empty.check([])
    empty.open(None)
    empty.close()
    assert list(tmp_path.iterdir()) == [] and said == []
    made = Video(tmp_path / "one.mp4", 30.0, tell=said.append)
    made.check([])
    made.open(None)
    made.sink.write(np.full((48, 64, 3), 128, np.uint8))
    made.close()
    assert made.frames == 1
    assert imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "one.mp4"))[0] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.mp4"]
