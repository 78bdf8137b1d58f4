"""The hw-sim command: prints the port, serves the real SDK, stops on Ctrl-C."""

from __future__ import annotations

import signal
import subprocess
import sys

import dynamixel_sdk as dxl

import hw_sim.cli


def test_help_lists_options(capsys):
    try:
        hw_sim.cli.main(["--help"])
    except SystemExit as exc:
        assert exc.code == 0
    out = capsys.readouterr().out
    for option in ("--servos", "--model", "--motion", "--faults", "--timing"):
        assert option in out


def test_bad_arguments_are_named(tmp_path, capsys):
    assert hw_sim.cli.main(["--servos", "5-2"]) == 2
    assert "--servos '5-2'" in capsys.readouterr().err
    bad = tmp_path / "f.txt"
    bad.write_text("1 dorp\n")
    assert hw_sim.cli.main(["--faults", str(bad)]) == 2
    assert f"{bad}:1" in capsys.readouterr().err


def test_serves_until_interrupted(interrupt_and_wait):
    proc = subprocess.Popen([sys.executable, "-m", "hw_sim.cli", "--servos", "1-14",
                             "--motion", "wave"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/pts/")
        port = dxl.PortHandler(path)
        assert port.openPort() and port.setBaudRate(1_000_000)
        packet = dxl.PacketHandler(2.0)
        assert [packet.ping(port, i)[:2] for i in (1, 14)] == [(1200, 0), (1200, 0)]
        port.closePort()
    finally:
        assert interrupt_and_wait(proc) == 0, proc.stderr.read()
