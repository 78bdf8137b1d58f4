"""A recording process killed with SIGKILL, or stopped with SIGTERM, at seeded random moments,
leaves a take that plays back everything it wrote."""

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from puppet.take import Playback, TakeReader

CHILD = Path(__file__).with_name("take_crash_child.py")
KILL_AFTER = np.random.default_rng(18).integers(20, 400, size=2).tolist()  # readings reported


def expected_ticks(i: int) -> list[int]:
    return [i, -3 * i, 4096 * i - 5, (i * 7919) % 100003 - 50000]


def record_then_signal(path, sig, background, after):
    """Run the child until it has reported `after` readings, send sig; (reported, kill_ns, rc)."""
    args = [sys.executable, str(CHILD), str(path)] + (["--background"] if background else [])
    child = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    buf = b""
    try:
        deadline = time.monotonic() + 60.0  # generous: CI is loaded
        while buf.count(b"\n") < after:
            assert time.monotonic() < deadline, f"child is too slow: {child.stderr.read1(4096)!r}"
            ready, _, _ = select.select([child.stdout], [], [], 0.05)
            if ready:
                chunk = os.read(child.stdout.fileno(), 65536)
                assert chunk != b"", f"child died: {child.stderr.read()!r}"
                buf += chunk
        kill_ns = time.monotonic_ns()
        child.send_signal(sig)
        rest, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
            child.communicate()
    out = buf + rest
    lines = out.splitlines()
    if not out.endswith(b"\n"):
        lines = lines[:-1]  # a line cut by the kill
    reported = [tuple(int(x) for x in line.split()) for line in lines]
    return reported, kill_ns, child.returncode, err


def check_readings(r, reported):
    got = list(r.readings())
    for i, reading in enumerate(got):  # exactly the child's sequence, in order, with its values
        assert reading.ticks.tolist() == expected_ticks(i)
        assert reading.ok.all()
    playback = Playback.of_take(r, r.metadata.ids, fps=60)  # and the take plays back
    frames = list(playback)
    assert len(frames) == len(playback)
    assert all(got[0].t_ns <= f.t_ns <= got[-1].t_ns for f in frames)
    return [reading.t_ns for reading in got]


@pytest.mark.parametrize("after", KILL_AFTER)
@pytest.mark.parametrize("background", [False, True])
def test_sigkill_mid_recording_keeps_everything_written(tmp_path, background, after):
    path = tmp_path / "killed.mcap"
    reported, kill_ns, rc, _ = record_then_signal(path, signal.SIGKILL, background, after)
    assert rc == -signal.SIGKILL
    assert len(reported) >= after
    r = TakeReader(path)
    assert r.truncated is True  # no footer: the writer never closed
    assert r.recovery is not None and r.report.skipped_count == 0
    got_t = check_readings(r, reported)
    # Everything up to 100 ms before the kill is there.
    before = [t for _, t in reported if t <= kill_ns - 100_000_000]
    assert got_t[: len(before)] == before
    if not background:
        # TakeWriter.write() returns after the OS has the record: nothing reported is lost.
        assert got_t[: len(reported)] == [t for _, t in reported]
    # At most the one reading written between the child's last report and the kill is extra.
    assert len(got_t) <= len(reported) + 1


@pytest.mark.parametrize("after", KILL_AFTER)
@pytest.mark.parametrize("background", [False, True])
def test_sigterm_closes_the_take_with_everything_written(tmp_path, background, after):
    path = tmp_path / "stopped.mcap"
    reported, _, rc, err = record_then_signal(path, signal.SIGTERM, background, after)
    assert rc == 0, err
    r = TakeReader(path)
    assert r.truncated is False and r.recovery is None  # closed cleanly
    got_t = check_readings(r, reported)
    assert got_t[: len(reported)] == [t for _, t in reported]
    assert len(got_t) <= len(reported) + 1
