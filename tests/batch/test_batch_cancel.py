"""Stopping a batch like a render farm, on both engines: SIGINT (a terminal's Ctrl-C, to the
whole process group) and SIGTERM (to the driver alone) mid-take stop the driver and every
process it started, remove the staging folders, print the summary so far and exit 128 + the
signal's number; a killed driver's workers die with it and its staging is removed by the next
run; --take-timeout stops a hung take and frees its worker; --retries are counted per take."""

import json
import os
import signal
import subprocess
import tempfile
from pathlib import Path

import pytest

from puppet.cli.batch import EXIT_DONE, EXIT_FAILED

PATIENCE_S = 120.0  # generous: a loaded 2-core machine, Ray shutting down
TAKE_TIMEOUT_S = 10  # --take-timeout of the hung-take test (the default scales with the take)

ENGINES = ["local", pytest.param("ray", marks=pytest.mark.skipif(
    __import__("importlib").util.find_spec("ray") is None, reason="ray is not installed"))]


def _stat(pid: int) -> tuple[int, int, int, str] | None:
    """(ppid, process group, start time, state) of a live process; None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), int(fields[2]), int(fields[19]), fields[0]


def _processes() -> dict[int, tuple[int, int, int, str]]:
    found = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (stat := _stat(int(entry))) is not None:
            found[int(entry)] = stat
    return found


def descendants(root: int) -> dict[int, int]:
    """{pid: start time} of every process below ``root`` now."""
    table = _processes()
    children: dict[int, list[int]] = {}
    for pid, (ppid, *_rest) in table.items():
        children.setdefault(ppid, []).append(pid)
    found, todo = {}, [root]
    while todo:
        for child in children.get(todo.pop(), []):
            found[child] = table[child][2]
            todo.append(child)
    return found


def still_running(snapshot: dict[int, int], group: int) -> list[int]:
    """Processes of ``snapshot`` (same start time: not a reused pid) or of process group
    ``group`` that are alive (zombies count as gone)."""
    alive = []
    for pid, (ppid, pgrp, start, state) in _processes().items():
        if state == "Z":
            continue
        if snapshot.get(pid) == start or pgrp == group:
            alive.append(pid)
    return alive


def staging_left(out: Path, driver: int) -> list[str]:
    """The driver's staging folders (in --out and in this machine's temporary folder) and any
    hidden temporary in --out."""
    left = [p.name for p in out.iterdir() if p.name.startswith(".")] if out.exists() else []
    temp = Path(tempfile.gettempdir())
    left += [str(p) for p in temp.glob(f".puppet-batch.*.{driver}.partial")]
    return left


def take_folders(out: Path, engine: str, driver: int, take: str) -> list[Path]:
    """Staging folders of ``take`` (``<take>.<worker pid>``) in the driver's staging."""
    base = out if engine == "local" else Path(tempfile.gettempdir())
    return list(base.glob(f".puppet-batch.*.{driver}.partial/{take}.*"))


def outputs(out: Path) -> list[str]:
    """The output files in --out (not the logs and manifests beside them)."""
    return sorted(p.name for p in out.iterdir() if p.suffix in (".glb", ".pc2", ".bvh", ".mp4"))


def on_cluster(engine: str, request) -> list:
    """The arguments that put a batch of ``engine`` on the session's Ray cluster (tests of a
    mechanism that is the same there as on a private instance); none for the local engine."""
    return request.getfixturevalue("on_ray_cluster") if engine == "ray" else []


def start(args, engine):
    # A neutral working folder, as a user's (Ray puts it on its workers' import path); a
    # session of its own, so the test can signal and check the batch's process group.
    command = ["puppet", "batch", *map(str, args), "--engine", engine, "--json"]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tempfile.gettempdir(), start_new_session=True)


def rows_of(stdout: str) -> dict[str, dict]:
    return {Path(r["take"]).name: r for r in json.loads(stdout.splitlines()[0])["takes"]}


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_mid_batch_stops_every_process_and_removes_staging(tmp_path, critter, tools,
                                                                   wait_until, engine, signum):
    long_takes = [tools.write_take(tmp_path / f"long{i}.mcap", critter, readings=900, seed=i)
                  for i in range(2)]
    short = tools.write_take(tmp_path / "short.mcap", critter, seed=5)
    out = tmp_path / "out"
    batch = start([*long_takes, short, "--out", out, "--formats", "pc2,gltf", "--workers", 2],
                  engine)
    try:
        wait_until(lambda: take_folders(out, engine, batch.pid, "long0")
                   or batch.poll() is not None, timeout=300, what="the first take started")
        assert batch.poll() is None, batch.communicate()[1]
        snapshot = descendants(batch.pid)
        assert snapshot, "the batch started no worker"
        if signum == signal.SIGINT:
            os.killpg(batch.pid, signal.SIGINT)  # Ctrl-C in a terminal: the whole group
        else:
            batch.send_signal(signal.SIGTERM)  # `kill`: the driver alone
        stdout, stderr = batch.communicate(timeout=PATIENCE_S)
    finally:
        if batch.poll() is None:
            os.killpg(batch.pid, signal.SIGKILL)
            batch.wait()
    assert batch.returncode == 128 + signum, stderr
    assert "Traceback" not in stderr
    name = signal.Signals(signum).name
    assert f"cancelled by {name}" in stderr
    rows = rows_of(stdout)
    assert sorted(rows) == ["long0.mcap", "long1.mcap", "short.mcap"]
    assert (rows["long0.mcap"]["state"], rows["long0.mcap"]["reason"]) == (
        "cancelled", f"cancelled by {name}")
    for row in rows.values():  # done or cancelled, never anything else
        assert row["state"] in ("done", "cancelled"), row
    wait_until(lambda: not still_running(snapshot, batch.pid), timeout=PATIENCE_S,
               what=f"every process of the batch gone (left: {still_running(snapshot, batch.pid)})")
    assert staging_left(out, batch.pid) == []
    done = [take for take, row in rows.items() if row["state"] == "done"]
    assert outputs(out) == sorted(
        f"{Path(take).stem}{suffix}" for take in done for suffix in (".glb", ".pc2"))
    assert sorted(p.name for p in out.glob("*.log")) == [f"{Path(t).stem}.log" for t in sorted(rows)]


@pytest.mark.parametrize("engine", ENGINES)
def test_a_killed_drivers_workers_die_and_the_next_run_removes_its_staging(tmp_path, critter,
                                                                         tools, wait_until,
                                                                         engine, request):
    long_take = tools.write_take(tmp_path / "long.mcap", critter, readings=900, seed=1)
    other = tools.write_take(tmp_path / "other.mcap", critter, seed=2)
    out = tmp_path / "out"
    batch = start([long_take, "--out", out, "--formats", "pc2", "--workers", 1], engine)
    try:
        wait_until(lambda: any(any(".partial" in p.name for p in folder.iterdir())
                               for folder in take_folders(out, engine, batch.pid, "long"))
                   or batch.poll() is not None, timeout=300, what="a half-written output")
        assert batch.poll() is None, batch.communicate()[1]
        snapshot = descendants(batch.pid)
        batch.kill()  # a crash of the driver: nothing of it runs
        batch.communicate(timeout=PATIENCE_S)
    finally:
        if batch.poll() is None:
            os.killpg(batch.pid, signal.SIGKILL)
            batch.wait()
    if engine == "local":  # its workers die with it (Ray's agents exit on their own, later)
        wait_until(lambda: not still_running(snapshot, -1), timeout=PATIENCE_S,
                   what="the killed driver's workers gone")
    assert staging_left(out, batch.pid) != []  # what the killed driver left
    # the next run (Ray: on the session's cluster; the stale staging is the driver's, wherever
    # its tasks run)
    after = subprocess.run(["puppet", "batch", other, "--out", out, "--formats", "pc2", "--json",
                            "--engine", engine, *on_cluster(engine, request)],
                           capture_output=True, text=True, timeout=600, cwd=tempfile.gettempdir())
    assert after.returncode == EXIT_DONE, after.stderr
    assert staging_left(out, batch.pid) == []
    assert outputs(out) == ["other.pc2"]


@pytest.mark.parametrize("engine", ENGINES)
def test_a_hung_take_times_out_and_its_worker_is_freed(tmp_path, critter, tools, wait_until,
                                                       engine, request):
    hung = tools.write_take(tmp_path / "hung.mcap", critter, readings=900, seed=3)
    after = tools.write_take(tmp_path / "after.mcap", critter, seed=4)
    out = tmp_path / "out"
    # one worker: the take after the hung one runs only once the hung one's worker is freed.
    # The time limit is the mechanism's, not the default's: short, yet long enough for `after`
    # (a short take) on a loaded machine.
    batch = start([hung, after, "--out", out, "--formats", "pc2", "--workers", 1,
                   "--take-timeout", TAKE_TIMEOUT_S, *on_cluster(engine, request)], engine)
    try:
        folder = wait_until(lambda: take_folders(out, engine, batch.pid, "hung")
                            or batch.poll() is not None, timeout=300, what="the take started")
        assert batch.poll() is None, batch.communicate()[1]
        worker = int(folder[0].suffix[1:])
        os.kill(worker, signal.SIGSTOP)  # hung: in a system call that never returns, say
        stdout, stderr = batch.communicate(timeout=600)
    finally:
        if batch.poll() is None:
            os.killpg(batch.pid, signal.SIGKILL)
            batch.wait()
    assert batch.returncode == EXIT_FAILED, stderr
    rows = rows_of(stdout)
    assert rows["hung.mcap"]["state"] == "timed out"
    assert rows["hung.mcap"]["reason"].startswith(
        f"still running after {TAKE_TIMEOUT_S} s (--take-timeout)")
    assert rows["after.mcap"]["state"] == "done"
    # killed (a cluster's raylet reaps it in its own time)
    wait_until(lambda: _stat(worker) is None or _stat(worker)[3] == "Z", timeout=PATIENCE_S,
               what="the hung worker killed")
    assert outputs(out) == ["after.pc2"]
    assert "timed out" in (out / "hung.log").read_text()


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("retries", [0, 1])
def test_retries_are_counted_per_take(tmp_path, critter, tools, wait_until, engine, retries,
                                     request):
    # long enough to be caught mid-take; the worker is stopped before it is looked at, so a
    # take found unfinished is killed unfinished
    long_take = tools.write_take(tmp_path / "long.mcap", critter, readings=200, seed=7)
    out = tmp_path / "out"
    batch = start([long_take, "--out", out, "--formats", "pc2", "--workers", 1,
                   "--retries", retries, *on_cluster(engine, request)], engine)
    try:
        folder = wait_until(lambda: take_folders(out, engine, batch.pid, "long")
                            or batch.poll() is not None, timeout=300, what="the take started")
        assert batch.poll() is None, batch.communicate()[1]
        worker = int(folder[0].suffix[1:])
        os.kill(worker, signal.SIGSTOP)
        # unfinished: its output neither written in its staging folder nor moved into --out
        ended = (folder[0] / "long.pc2").exists() or (out / "long.pc2").exists()
        os.kill(worker, signal.SIGKILL)  # out of memory, say
        assert not ended, "the take ended before its worker was stopped"
        stdout, stderr = batch.communicate(timeout=600)
    finally:
        if batch.poll() is None:
            os.killpg(batch.pid, signal.SIGKILL)
            batch.wait()
    assert len(stdout.splitlines()) == 1, stdout  # the report alone: nothing raw of Ray's
    assert "\x1b[" not in stdout + stderr
    row = rows_of(stdout)["long.mcap"]
    if retries:
        assert batch.returncode == EXIT_DONE, stderr
        assert (row["state"], row["retries"]) == ("done", 1)
        assert (out / "long.pc2").read_bytes() == tools.serial(long_take, tmp_path / "serial",
                                                               ("pc2",))["pc2"]
    else:
        assert batch.returncode == EXIT_FAILED, stderr
        assert (row["state"], row["retries"]) == ("failed", 0)
        assert "died" in row["reason"]
        assert outputs(out) == []
