"""A take is never destroyed by a mistake: ``puppet record`` and ``puppet live --record`` open the
port before the take, refuse an existing take without --force, never write over a rig file,
end on a full disk with an error naming the take, and close the take on SIGTERM."""

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import hw_sim
from puppet.reading import Reading
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader, TakeWriter

PUPPET = Path(sys.executable).with_name("puppet")
NO_PORT = "/dev/puppet-no-such-port"


def run(*args, timeout=180):
    return subprocess.run([str(PUPPET), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def assert_clean_error(result, *names):
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr and "internal error" not in result.stderr
    error = [line for line in result.stderr.splitlines() if line.startswith("Error: ")]
    assert len(error) == 1, result.stderr
    for name in names:
        assert str(name) in error[0]
    return error[0]


def models():
    from puppet.rig import builtin

    return builtin().servo_map.models


@pytest.fixture
def rig_copy(tmp_path):
    """The built-in rig's files, copied: a command that wrongly wrote over them harms nothing."""
    folder = tmp_path / "rig"
    folder.mkdir()
    for name in ("critter.toml", "critter.npz"):
        shutil.copy(BUILTIN_RIG.with_name(name), folder / name)
    return folder / "critter.toml"


@pytest.fixture
def old_take(tmp_path):
    """A take recorded earlier with the built-in rig: 50 readings."""
    from puppet.rig import builtin

    rig = builtin()
    k = len(rig.servo_map)
    path = tmp_path / "precious.mcap"
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=models(),
                    rig_map_text="", calibration_text="", rig_name=rig.name) as w:
        for i in range(50):
            w.write(Reading(i * 2_000_000, rig.servo_map.ids,
                            np.full(k, 2048 + i, np.int32), np.ones(k, bool)))
    return path


def test_wrong_port_leaves_an_existing_take_alone(old_take, tmp_path):
    before = old_take.read_bytes()
    result = run("record", "--rig", BUILTIN_RIG, "--port", NO_PORT, "--out", old_take, "--force")
    assert_clean_error(result, NO_PORT)
    assert old_take.read_bytes() == before  # the port is opened before the take
    new = tmp_path / "new.mcap"
    result = run("record", "--rig", BUILTIN_RIG, "--port", NO_PORT, "--out", new)
    assert_clean_error(result, NO_PORT)
    assert not new.exists()


def test_record_refuses_an_existing_take_without_force(old_take):
    before = old_take.read_bytes()
    with hw_sim.serve(models()) as bus:
        result = run("record", "--rig", BUILTIN_RIG, "--port", bus.port, "--out", old_take,
                     "--seconds", 0.5)
        error = assert_clean_error(result, old_take)
        assert "exists; pass --force to overwrite it" in error
        assert old_take.read_bytes() == before
        result = run("record", "--rig", BUILTIN_RIG, "--port", bus.port, "--out", old_take,
                     "--seconds", 0.5, "--rate", 100, "--force")
    assert result.returncode == 0, result.stderr
    readings = int(re.search(r"readings: (\d+)", result.stdout).group(1))
    assert len(TakeReader(old_take)) == readings > 0


def test_record_never_writes_over_the_rig_files(rig_copy):
    files = {p: p.read_bytes() for p in rig_copy.parent.iterdir()}
    for target in files:
        result = run("record", "--rig", rig_copy, "--port", NO_PORT, "--out", target, "--force")
        error = assert_clean_error(result, target)
        assert "the take is also an input of this command" in error
    assert {p: p.read_bytes() for p in rig_copy.parent.iterdir()} == files


def test_live_record_refuses_an_existing_take_without_force(old_take):
    before = old_take.read_bytes()
    with hw_sim.serve(models()) as bus:
        result = run("live", "--rig", BUILTIN_RIG, "--port", bus.port, "--record", old_take,
                     "--seconds", 0.5)
    error = assert_clean_error(result, old_take)
    assert "exists; pass --force to overwrite it" in error
    assert old_take.read_bytes() == before


def test_record_on_a_full_disk_is_an_error_and_keeps_the_readings(small_disk):
    take = small_disk / "take.mcap"
    with hw_sim.serve(models(), motion="wave") as bus:
        result = run("record", "--rig", BUILTIN_RIG, "--port", bus.port, "--out", take,
                     "--seconds", 120)
    error = assert_clean_error(result, take)
    assert "the disk is full" in error
    kept = int(re.search(r"the (\d+) readings before it are kept", error).group(1))
    reader = TakeReader(take)
    assert len(reader) == kept > 0
    assert reader.truncated is True and reader.report.skipped_count == 0


def test_sigterm_closes_the_take(tmp_path):
    take = tmp_path / "take.mcap"
    with hw_sim.serve(models(), motion="wave") as bus:
        proc = subprocess.Popen([str(PUPPET), "record", "--rig", str(BUILTIN_RIG), "--port",
                                 bus.port, "--out", str(take), "--rate", "200"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and (not take.exists()
                                                   or take.stat().st_size < 20_000):
                time.sleep(0.05)
            os.kill(proc.pid, signal.SIGTERM)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert proc.returncode == 0, err
    readings = int(re.search(r"readings: (\d+)", out).group(1))
    reader = TakeReader(take)
    assert reader.truncated is False and reader.recovery is None
    assert len(reader) == readings > 0


def test_a_record_stopped_before_its_first_reading_says_no_file_was_made(tmp_path):
    """SIGTERM during the count-in (no reading belongs to the take yet): the summary says no
    file was made, as none is, instead of naming a take that does not exist."""
    take = tmp_path / "take.mcap"
    with hw_sim.serve(models()) as bus:
        proc = subprocess.Popen([str(PUPPET), "record", "--rig", str(BUILTIN_RIG), "--port",
                                 bus.port, "--out", str(take), "--count-in", "60"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 120
            seen = ""
            line = ""
            while time.monotonic() < deadline and not line.strip().isdigit() \
                    and proc.poll() is None:
                line = proc.stderr.readline()  # the count-in's first number: setup is done
                seen += line
            os.kill(proc.pid, signal.SIGTERM)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    err = seen + err
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert f"take: {take} (nothing recorded: no file)" in out, out
    assert "readings: 0 " in out, out
    assert "the take holds every reading" not in err, err
    assert not take.exists()
