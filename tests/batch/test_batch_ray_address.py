"""Where ``--engine ray`` runs: a private instance unless told otherwise (a cluster already
running here is never joined, and ``--workers`` works), ``--address auto`` joins that cluster,
and an address that is not a Ray head fails at once naming it, with nothing raw of Ray's."""

import json
import socket
import subprocess
import tempfile
import threading

import pytest

pytest.importorskip("ray", reason="ray is not installed (pip install 'puppet[ray]')")

from puppet.batch.errors import BatchError  # noqa: E402 - after the skip
from puppet.batch.ray_engine import CONNECT_TIMEOUT_ENV, CONNECT_TIMEOUT_S, connect_timeout_s  # noqa: E402


def batch(*args, timeout=600):
    return subprocess.run(["puppet", "batch", *map(str, args), "--engine", "ray"],
                          capture_output=True, text=True, timeout=timeout,
                          cwd=tempfile.gettempdir())


def assert_clean_error(result, address, words):
    assert result.returncode == 1, result.stderr
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert lines == [lines[0]], result.stderr  # one line: no raw warnings of Ray's
    assert lines[0].startswith(f"Error: --address {address}: "), lines[0]
    assert words in lines[0]


def test_an_address_that_accepts_but_is_not_ray_fails_naming_it(tmp_path, session, monkeypatch):
    # the wait for an answer is the mechanism's (the default CONNECT_TIMEOUT_S is 10 s)
    monkeypatch.setenv(CONNECT_TIMEOUT_ENV, "1.5")
    listener = socket.create_server(("127.0.0.1", 0))
    address = f"127.0.0.1:{listener.getsockname()[1]}"
    held = []

    def accept():  # accepts every connection and never answers, like a stuck service
        while True:
            try:
                held.append(listener.accept()[0])
            except OSError:
                return

    threading.Thread(target=accept, daemon=True).start()
    try:
        # the generous limit is for a loaded machine
        result = batch(session[0], "--out", tmp_path / "out", "--address", address, timeout=120)
    finally:
        listener.close()
        for connection in held:
            connection.close()
    assert held, "the batch never connected"
    assert_clean_error(result, address, "not a Ray head (no gRPC answer within 1.5 s)")
    assert not any((tmp_path / "out").iterdir())


def test_an_address_that_is_not_host_and_port_is_refused_naming_it(tmp_path, session):
    # (nothing listening: tests/batch/test_batch_bad_input.py)
    result = batch(session[0], "--out", tmp_path / "out", "--address", "nonsense", timeout=120)
    assert_clean_error(result, "nonsense", "expected host:port")


@pytest.mark.xdist_group("batch-ray")  # one Ray instance at a time (tests/conftest.py)
def test_a_private_instance_unless_address_auto_joins_the_running_cluster(tmp_path, session,
                                                                       serial_outputs,
                                                                       ray_cluster,
                                                                       monkeypatch):
    # the session's cluster (tests/batch/conftest.py), started as a user does
    monkeypatch.setenv("RAY_ADDRESS", ray_cluster)  # what `ray start` asks users to set
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    out = tmp_path / "out"
    result = batch(*session[:2], "--out", out, "--formats", "pc2", "--workers", 2, "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert [row["state"] for row in report["takes"]] == ["done", "done"]
    for take in session[:2]:
        assert (out / f"{take.stem}.pc2").read_bytes() == serial_outputs[take.stem]["pc2"]
    assert result.stderr.count("\n") <= 2, result.stderr  # the progress bar, nothing of Ray's
    # --address auto joins it (--workers only bounds the tasks at once there)
    joined = batch(*session[2:], "--out", out, "--formats", "pc2", "--workers", 2, "--json",
                   "--address", "auto")
    assert joined.returncode == 0, joined.stderr
    assert [row["state"] for row in json.loads(joined.stdout)["takes"]] == ["done", "done"]
    for take in session[2:]:
        assert (out / f"{take.stem}.pc2").read_bytes() == serial_outputs[take.stem]["pc2"]


def test_the_wait_for_a_ray_head_is_the_default_unless_the_environment_says(monkeypatch):
    monkeypatch.delenv(CONNECT_TIMEOUT_ENV, raising=False)
    assert connect_timeout_s() == CONNECT_TIMEOUT_S == 10.0
    monkeypatch.setenv(CONNECT_TIMEOUT_ENV, "0.5")
    assert connect_timeout_s() == 0.5
    for bad in ("soon", "0", "-3", "nan"):
        monkeypatch.setenv(CONNECT_TIMEOUT_ENV, bad)
        with pytest.raises(BatchError, match=f"^{CONNECT_TIMEOUT_ENV}='{bad}': must be a number "):
            connect_timeout_s()
