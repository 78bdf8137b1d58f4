"""The console commands exist, print real usage, and refuse bad input with exit 2."""

import subprocess
import sys


def run(*args):
    return subprocess.run(list(args), capture_output=True, text=True, timeout=60)


def test_puppet_help_lists_commands():
    result = run("puppet", "--help")
    assert result.returncode == 0
    for command in ("demo", "live", "record", "play", "scan", "calibrate", "export", "rig"):
        assert command in result.stdout


def test_puppet_unknown_subcommand_prints_usage_and_exits_2():
    result = run("puppet", "dance")
    assert result.returncode == 2
    assert "Usage:" in result.stderr
    assert "Traceback" not in result.stderr
    error = [line for line in result.stderr.splitlines() if line.startswith("Error: ")]
    assert len(error) == 1 and "dance" in error[0]


def test_puppet_bad_option_exits_2():
    result = run("puppet", "demo", "--seconds", "many")
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    error = [line for line in result.stderr.splitlines() if line.startswith("Error: ")]
    assert len(error) == 1 and "--seconds" in error[0]


def test_hw_sim_help_prints_usage():
    result = run("hw-sim", "--help")
    assert result.returncode == 0
    assert "usage: hw-sim" in result.stdout
    assert "--servos" in result.stdout


def test_hw_sim_bad_option_exits_2():
    result = run("hw-sim", "--no-such-option")
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "error: unrecognized arguments: --no-such-option" in result.stderr


def test_hw_sim_does_not_import_puppet():
    code = "import sys, hw_sim, hw_sim.cli; print(any(m.split('.')[0] == 'puppet' for m in sys.modules))"
    result = run(sys.executable, "-P", "-c", code)
    assert result.stdout.strip() == "False"
