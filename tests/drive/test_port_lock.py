"""One program per port: while ``perform``, ``live`` or ``record`` holds a bus (hw_sim's pty,
the real SDK), each of ``perform``, ``live``, ``record``, ``calibrate`` and ``scan`` started on
that port exits 1 with an ``Error:`` line naming the port and the process holding it, and the
holder carries on untouched."""

from __future__ import annotations

import fcntl
import os
import signal
import subprocess
import time

import numpy as np
import pytest

import hw_sim
from puppet.reading import Reading
from puppet.rig import Calibration, builtin
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeWriter

HOLDERS = ("perform", "live", "record")
INTRUDERS = ("perform", "live", "record", "calibrate", "scan")
WAIT_S = 120.0  # generous: a loaded 2-core machine


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    """A 1 s take of the built-in rig at rest."""
    rig = builtin()
    sm = rig.servo_map
    path = tmp_path_factory.mktemp("lock") / "rest.mcap"
    calibration = Calibration.capture(sm.ids, sm.zero)
    with TakeWriter(path, ids=sm.ids, models=dict(sm.models), rig_map_text="",
                    calibration_text=calibration.to_record(), rig_name=rig.name) as writer:
        for n in range(100):
            writer.write(Reading(int(n * 1e7), sm.ids, sm.zero.astype(np.int32),
                                 np.ones(len(sm.ids), bool)))
    return path


def _command(name: str, port: str, take, tmp, hold: bool) -> list[str]:
    """The command line of ``name`` on ``port``; ``hold``: it keeps the port until stopped."""
    seconds = ["--seconds", "600" if hold else "1"]
    return {
        "perform": ["puppet", "perform", str(take), "--port", port, "--yes",
                    "--latency-ms", "20", "--watchdog-ms", "2000"] + (["--loop"] if hold else []),
        "live": ["puppet", "live", "--rig", str(BUILTIN_RIG), "--port", port, *seconds],
        "record": ["puppet", "record", "--rig", str(BUILTIN_RIG), "--port", port,
                   "--out", str(tmp / "take.mcap"), "--force", *seconds],
        "calibrate": ["puppet", "calibrate", "--rig", str(BUILTIN_RIG), "--port", port,
                      "--out", str(tmp / "calibration.json")],
        "scan": ["puppet", "scan", "--port", port],
    }[name]


def _wait(condition, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def _locked(port: str) -> bool:
    """Whether some process holds the port's lock (tried without taking it for long)."""
    fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # closing releases a lock taken here
    return False


@pytest.fixture(scope="module", params=HOLDERS)
def holder(request, take, tmp_path_factory):
    """(name, process, port): a command holding a simulated bus of the built-in rig's servos."""
    tmp = tmp_path_factory.mktemp("holder")
    rig = builtin()
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        port = bus.port
        proc = subprocess.Popen(_command(request.param, port, take, tmp, hold=True),
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            _wait(lambda: _locked(port) or proc.poll() is not None, f"{request.param} on {port}")
            assert proc.poll() is None, proc.stderr.read()
            yield request.param, proc, port
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=WAIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _intrude(argv: list[str], end_to_end: bool) -> tuple[int, str]:
    """(exit code, stderr) of ``argv`` (``puppet ...``): a process of its own as a user starts
    it, or (not ``end_to_end``) the same command line run in this process by click's runner
    (the port's lock is another process's either way; no interpreter start-up)."""
    if end_to_end:
        result = subprocess.run(argv, capture_output=True, text=True, timeout=WAIT_S)
        return result.returncode, result.stderr
    from click.testing import CliRunner

    from puppet.cli import main

    result = CliRunner().invoke(main, argv[1:])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return result.exit_code, result.stderr


@pytest.mark.parametrize("intruder", INTRUDERS)
def test_a_second_program_on_a_port_is_refused_naming_the_holder(holder, intruder, take,
                                                                 tmp_path):
    """Each holder meets its own command as a separate program (end to end); the other
    intruders run in-process."""
    name, proc, port = holder
    code, stderr = _intrude(_command(intruder, port, take, tmp_path, hold=False),
                            end_to_end=intruder == name)
    assert code == 1, stderr
    assert "Traceback" not in stderr
    errors = [line for line in stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1, stderr
    assert errors[0].startswith(f"Error: port {port}: in use by pid {proc.pid} (puppet {name} "), errors
    assert proc.poll() is None  # the holder goes on
