"""Shared data of the batch tests: short takes of the built-in critter, written with TakeWriter,
and each take exported and played alone by the serial commands (the reference bytes); one Ray
cluster for the session (``ray_cluster``), joined by the Ray tests that need no private instance."""

import fcntl
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.take import TakeWriter

READINGS = 10  # a third of a second at 30 readings per second: 10 frames per output
SERIAL_FORMATS = {"gltf": ".glb", "usd": ".usdc", "pc2": ".pc2", "bvh": ".bvh"}


def write_take(path, rig, readings=READINGS, seed=0, rig_name=None):
    """A take of ``rig`` at 30 readings per second, every servo moving (``seed`` varies it)."""
    k = len(rig.servo_map)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig_name or rig.name,
                    overwrite=True) as writer:
        for i in range(readings):
            ticks = (rig.servo_map.zero + 300 * np.sin(0.2 * i + seed + np.arange(k))).astype(np.int32)
            writer.write(Reading(1_000_000_000 + round(i * 1e9 / 30), rig.servo_map.ids, ticks,
                                 np.ones(k, bool)))
    return Path(path)


def serial(take: Path, folder: Path, formats) -> dict[str, bytes]:
    """{format: bytes} of ``puppet export`` / ``puppet play`` run on the take alone."""
    folder.mkdir(exist_ok=True)
    exports = [f for f in formats if f in SERIAL_FORMATS]
    files = {f: folder / f"{take.stem}{SERIAL_FORMATS[f]}" for f in exports}
    if exports:
        args = [a for f in exports for a in (f"--{f}", files[f])]
        subprocess.run(["puppet", "export", take, *args], check=True, capture_output=True,
                       timeout=300)
    if "mp4" in formats:
        files["mp4"] = folder / f"{take.stem}.mp4"
        subprocess.run(["puppet", "play", take, "--out", files["mp4"]], check=True,
                       capture_output=True, timeout=300)
    return {f: p.read_bytes() for f, p in files.items()}


def puppet_here(*args) -> SimpleNamespace:
    """``puppet ARGS`` run in this process (click's CliRunner through ``puppet.cli.main``: the
    same command, its errors and its output; no fresh interpreter): (returncode, stdout,
    stderr). End-to-end runs of the command stay where the process is the subject (signals,
    exit of workers, Ray)."""
    from click.testing import CliRunner

    from puppet.cli import main

    result = CliRunner().invoke(main, [*map(str, args)])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exc_info
    return SimpleNamespace(returncode=result.exit_code, stdout=result.stdout,
                           stderr=result.stderr)


@pytest.fixture(autouse=True)
def _own_signal_handlers():
    """The test process's SIGINT and SIGTERM handlers given back after each test (importing the
    command line keeps early signals for its commands: ``puppet.session.signals.early``)."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)


@pytest.fixture(scope="session")
def critter():
    from puppet.rig import builtin

    return builtin()


def made_once(tmp_path_factory, name: str, fill: Callable[[Path], object]) -> Path:
    """A folder that ``fill(folder)`` fills once per test run, read-only after. Under
    pytest-xdist the workers share it (in the run's own temporary folder, above each worker's):
    the first to need it fills it under a file lock while the others wait, then they all read
    the same files; in one process, a temporary folder of its own."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        folder = tmp_path_factory.mktemp(name)
        fill(folder)
        return folder
    folder = tmp_path_factory.getbasetemp().parent / name
    with open(f"{folder}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when closed
        filled = folder / ".filled"
        if not filled.exists():
            shutil.rmtree(folder, ignore_errors=True)  # a worker that died while filling it
            folder.mkdir()
            fill(folder)
            filled.touch()
    return folder


@pytest.fixture(scope="session")
def session(tmp_path_factory, critter):
    """Four short takes of the critter, different motions (read only: every worker of the run
    reads the same files): [Path]."""
    names = [f"take{i:02d}.mcap" for i in range(4)]
    folder = made_once(tmp_path_factory, "batch-session", lambda folder: [
        write_take(folder / name, critter, seed=i) for i, name in enumerate(names)])
    return [folder / name for name in names]


@pytest.fixture(scope="session")
def serial_outputs(tmp_path_factory, session):
    """{take name: {format: bytes}} of every format made by the serial commands (made once per
    run: the serial-batch and Ray workers compare with the same files)."""
    formats = ("mp4", "gltf", "usd", "pc2", "bvh")
    folder = made_once(tmp_path_factory, "batch-serial", lambda folder: [
        serial(take, folder, formats) for take in session])
    suffixes = {**SERIAL_FORMATS, "mp4": ".mp4"}
    return {take.stem: {f: (folder / f"{take.stem}{suffixes[f]}").read_bytes() for f in formats}
            for take in session}


RAY_CPUS = 2
RAY_READY_S = 300.0  # generous: `ray start` on a loaded 2-core machine


@pytest.fixture(scope="session")
def ray_cluster():
    """A Ray cluster started on this machine as a user does (``ray start --head --block``), of
    RAY_CPUS CPUs, shared by the session's Ray tests that join a running cluster (``--address``;
    tests/conftest.py keeps them in one worker): one start instead of a private instance per
    batch. Its address, "127.0.0.1:port", once it said it runs. Its processes (its own process
    group only) are killed at the end: a graceful stop of `ray start --block` takes about 30 s,
    and nothing of it outlives its group and temporary folder."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    temp = tempfile.mkdtemp(prefix="ray-")  # short: Ray's socket paths live under it
    log = Path(temp) / "start.log"
    with open(log, "w") as out:
        head = subprocess.Popen([sys.executable, "-m", "ray.scripts.scripts", "start", "--head",
                                 "--block", f"--port={port}", f"--num-cpus={RAY_CPUS}",
                                 "--include-dashboard=false", "--disable-usage-stats",
                                 f"--temp-dir={temp}"],
                                stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                                env={**os.environ, "RAY_AUTH_MODE": "disabled"})
    try:
        deadline = time.monotonic() + RAY_READY_S
        while "Ray runtime started" not in log.read_text():
            assert head.poll() is None, f"ray start exited {head.returncode}: {log.read_text()}"
            assert time.monotonic() < deadline, f"ray start not up in {RAY_READY_S} s"
            time.sleep(0.2)
        yield f"127.0.0.1:{port}"
    finally:
        os.killpg(head.pid, signal.SIGKILL)
        head.wait()
        shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture
def on_ray_cluster(ray_cluster, monkeypatch):
    """The arguments that run a batch on the session's cluster: ["--address", address] (Ray's
    token mode off for the drivers, as the cluster was started)."""
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    return ["--address", ray_cluster]


@pytest.fixture
def tools():
    return SimpleNamespace(write_take=write_take, serial=serial, puppet=puppet_here)
