"""Bad input to ``puppet batch``: a clear ``Error:`` line, exit 1, no traceback, before any take
is solved and with nothing written."""

import subprocess
import sys

import pytest


def run(*args, python_prefix=None):
    command = (["puppet"] if python_prefix is None
               else [sys.executable, "-P", "-c", python_prefix + "from puppet.cli import main; main()"])
    return subprocess.run([*command, "batch", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def assert_clean_error(result, *words):
    assert result.returncode == 1, result.stderr
    assert "Error:" in result.stderr
    assert "Traceback" not in result.stderr
    for word in words:
        assert word in result.stderr, result.stderr


def test_no_takes_matched(tmp_path, tools):
    assert_clean_error(run(tmp_path / "nothing*.mcap", "--out", tmp_path / "out"),
                       "nothing*.mcap", "no takes matched")  # the command, end to end
    assert_clean_error(tools.puppet("batch", tmp_path / "missing.mcap", "--out", tmp_path / "out"),
                       "missing.mcap", "no such take file")
    assert_clean_error(tools.puppet("batch", "--out", tmp_path / "out"), "no takes given")
    assert not (tmp_path / "out").exists()


def test_an_output_folder_that_cannot_be_written(tmp_path, session, tools):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert_clean_error(tools.puppet("batch", session[0], "--out", blocker / "out"),
                       str(blocker / "out"), "cannot create the output folder")
    assert_clean_error(tools.puppet("batch", session[0], "--out", blocker), str(blocker))
    assert blocker.read_text() == "not a folder"


def test_bad_formats_and_sizes(tmp_path, session, tools):
    def run(*args):
        return tools.puppet("batch", *args)

    assert_clean_error(run(session[0], "--out", tmp_path, "--formats", "gltf,fbx"), "'fbx'",
                       "mp4, gltf, usd, pc2, bvh")
    assert_clean_error(run(session[0], "--out", tmp_path, "--formats", "mp4", "--size", 641, 480),
                       "641x480", "even")
    assert_clean_error(run(session[0], "--out", tmp_path, "--fps", 0), "frames per second")
    assert list(tmp_path.iterdir()) == []


def test_ray_missing_is_named_with_its_install_command(tmp_path, session):
    hide_ray = "import sys; sys.modules['ray'] = None\n"  # `import ray` raises ImportError
    result = run(session[0], "--out", tmp_path / "out", "--engine", "ray", python_prefix=hide_ray)
    assert_clean_error(result, "Ray is not installed", "pip install 'puppet[ray]'")
    assert list((tmp_path / "out").iterdir()) == []


def test_an_unreachable_ray_address_fails_before_any_work(tmp_path, session):
    pytest.importorskip("ray", reason="ray is not installed (pip install 'puppet[ray]')")
    result = run(session[0], "--out", tmp_path / "out", "--engine", "ray", "--address",
                 "127.0.0.1:9")
    assert_clean_error(result, "--address 127.0.0.1:9", "no Ray head answers there")
    assert list((tmp_path / "out").iterdir()) == []
    assert_clean_error(run(session[0], "--out", tmp_path / "out", "--address", "127.0.0.1:9"),
                       "--address is for --engine ray")


def test_a_fifo_or_folder_named_like_a_take_is_a_failed_row_not_a_hang(tmp_path, session,
                                                                        tools):
    import json
    import os

    folder = tmp_path / "takes"
    folder.mkdir()
    os.mkfifo(folder / "pipe.mcap")
    (folder / "folder.mcap").mkdir()
    (folder / "good.mcap").write_bytes(session[0].read_bytes())
    out = tmp_path / "out"
    result = tools.puppet("batch", folder, "--out", out, "--formats", "bvh", "--workers", 1,
                          "--json")
    assert result.returncode == 3 and "Traceback" not in result.stderr  # some takes failed
    rows = {r["take"]: r for r in json.loads(result.stdout)["takes"]}
    for name in ("pipe.mcap", "folder.mcap"):
        assert rows[str(folder / name)]["state"] == "failed"
        assert rows[str(folder / name)]["reason"] == (
            f"{folder / name}: not a regular file (a folder, FIFO or device): a take is an MCAP "
            "file")
    assert rows[str(folder / "good.mcap")]["state"] == "done"
