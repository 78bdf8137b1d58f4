"""One studio per session folder: a second is refused naming the first (pid, command); the lock
of a studio that was killed is taken over, and said."""

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from puppet.studio import SessionFolder, SessionInUse, SessionWriter

HOLDER = Path(__file__).with_name("hold_session.py")


def hold(folder):
    child = subprocess.Popen([sys.executable, str(HOLDER), str(folder)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline() == "ready\n"  # blocks until the child holds the lock
    return child


def test_a_second_studio_is_refused_naming_the_first(tmp_path, kit):
    folder = tmp_path / "s"
    with SessionWriter.open(folder) as session:
        kit.record(session)
    child = hold(folder)
    try:
        with pytest.raises(SessionInUse) as refused:
            SessionWriter.open(folder)
        message = str(refused.value)
        assert f"pid {child.pid} (" in message and "hold_session.py" in message
        assert str(folder) in message and "one studio per session folder" in message
        assert refused.value.holder.startswith(f"pid {child.pid} ")
        lock_text = (folder / "session.lock").read_text()  # a person can read who holds it
        assert lock_text.startswith(f"pid {child.pid}\ncommand ") and "hold_session.py" in lock_text
        assert len(SessionFolder.read(folder).index.shots) == 1  # reading needs no lock
        cli = subprocess.run(["puppet", "session", "circle", str(folder), "shot 1", "1"],
                             capture_output=True, text=True, timeout=120)
        assert cli.returncode == 1 and "Traceback" not in cli.stderr
        assert f"Error: {folder}: session in use by pid {child.pid}" in cli.stderr
    finally:
        child.stdin.close()
        assert child.wait(timeout=60) == 0
    with SessionWriter.open(folder) as session:  # the first one ended: free, nothing to say
        assert session.notes == []


def test_the_same_process_cannot_open_it_twice(tmp_path):
    with SessionWriter.open(tmp_path / "s"):
        with pytest.raises(SessionInUse, match="this process"):
            SessionWriter.open(tmp_path / "s")


def test_a_killed_studios_lock_is_taken_over_and_said(tmp_path, kit):
    folder = tmp_path / "s"
    child = hold(folder)
    child.send_signal(signal.SIGKILL)
    assert child.wait(timeout=60) == -signal.SIGKILL
    assert (folder / "session.lock").read_text().startswith(f"pid {child.pid}\n")  # stale
    with SessionWriter.open(folder) as session:
        assert len(session.notes) == 1
        note = session.notes[0]
        assert f"took over the lock of pid {child.pid} (" in note
        assert "hold_session.py" in note and "no longer running" in note
        kit.record(session)
    assert (folder / "session.lock").read_text() == ""
