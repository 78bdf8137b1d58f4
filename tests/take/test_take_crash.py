"""A recording process killed with SIGKILL leaves a take that plays back what it wrote."""

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from puppet.take import PlaybackClock, TakeReader

CHILD = Path(__file__).with_name("take_crash_child.py")


def expected_ticks(i: int) -> list[int]:
    return [i, -3 * i, 4096 * i - 5, (i * 7919) % 100003 - 50000]


@pytest.mark.parametrize("background", [False, True])
def test_sigkill_mid_recording_keeps_everything_written(tmp_path, background):
    path = tmp_path / "killed.mcap"
    args = [sys.executable, str(CHILD), str(path)] + (["--background"] if background else [])
    child = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    buf = b""
    try:
        # Wait (generously, CI is loaded) until the child has reported 60 readings, the first
        # one 300 ms old or more, then kill: a count, not a duration (a loaded machine records
        # fewer per second).
        deadline = time.monotonic() + 120.0

        def enough():
            lines = buf.split(b"\n")
            return (len(lines) > 60 and
                    int(lines[0].split()[1]) <= time.monotonic_ns() - 300_000_000)

        while not enough():
            now = time.monotonic()
            assert now < deadline, f"child wrote too little: {child.stderr.read1(4096)!r}"
            ready, _, _ = select.select([child.stdout], [], [], 0.01)
            if ready:
                chunk = os.read(child.stdout.fileno(), 65536)
                assert chunk != b"", f"child died: {child.stderr.read()!r}"
                buf += chunk
        kill_ns = time.monotonic_ns()
        child.send_signal(signal.SIGKILL)
    finally:
        child.kill()
        rest, _ = child.communicate()
    assert child.returncode == -signal.SIGKILL
    out = buf + rest
    lines = out.splitlines()
    if not out.endswith(b"\n"):
        lines = lines[:-1]  # a line cut by the kill
    reported = [tuple(int(x) for x in line.split()) for line in lines]
    assert len(reported) >= 60

    r = TakeReader(path)
    assert r.truncated is True  # no footer: the writer never closed
    assert r.recovery is not None
    got = list(r.readings())
    # Recovered readings are exactly the child's sequence, in order, with their values.
    for i, reading in enumerate(got):
        assert reading.ticks.tolist() == expected_ticks(i)
        assert reading.ok.all()
    got_t = [reading.t_ns for reading in got]
    # Everything up to 100 ms before the kill is there.
    before = [t for _, t in reported if t <= kill_ns - 100_000_000]
    assert len(before) > 0
    assert got_t[: len(before)] == before
    if not background:
        # TakeWriter.write() returns after the OS has the record: nothing reported is lost.
        assert got_t[: len(reported)] == [t for _, t in reported]
    # At most the one reading written between the child's last report and the kill is extra.
    assert len(got) <= len(reported) + 1
    # And the recovered take plays back.
    frames = list(PlaybackClock(r, fps=60))
    assert len(frames) == len(PlaybackClock(r, fps=60))
    assert got_t[-1] - 1e9 / 60 < frames[-1].take_t_ns <= got_t[-1]
    assert all(f.reading.t_ns <= f.take_t_ns for f in frames)
    assert np.all(np.diff([f.take_t_ns for f in frames]) > 0)
