"""One program per port: an exclusive advisory lock (``flock``) on the opened serial device.

Two programs on one bus undo each other (one turns torque on for the other's sensors, off
for its actuators, clears its watchdog). ``BusLink.open`` locks the device it opened, without
waiting (a pseudo-terminal such as hw_sim's too); when another process holds it, ``PortInUse``
names that process: pid and command line, from ``/proc/locks`` (Linux; elsewhere the error
says only that the port is in use). The lock belongs to the open file: closing the port, or
the process dying (even by SIGKILL), releases it.
"""

from __future__ import annotations

import fcntl
import os

from puppet.bus.errors import PortError


class PortInUse(PortError):
    """Another process holds the port's lock. ``holder``: that process in words, or None."""

    def __init__(self, port: str, holder: str | None):
        self.holder = holder
        super().__init__(port, f"in use by {holder or 'another process'}: one program per port "
                               "(stop that one first)")

    def __reduce__(self):
        return (PortInUse, (self.port, self.holder))


def lock(fd: int, port: str) -> None:
    """Take the exclusive lock on the open device ``fd`` of ``port`` (at once, or PortInUse)."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise PortInUse(port, holder(fd)) from None


def holder(fd: int) -> str | None:
    """The process holding a flock on the file of ``fd``, in words ('pid 4242 (puppet live
    --rig r.toml ...)'), or None when it cannot be told."""
    st = os.fstat(fd)
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        with open("/proc/locks") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return None
    for line in lines:
        fields = line.split()
        # "1: FLOCK  ADVISORY  WRITE 4276 00:1a:4 0 EOF" (a blocked waiter has "->" after "1:")
        if len(fields) >= 6 and "FLOCK" in fields[1:3] and fields[5] == key and fields[1] != "->":
            pid = int(fields[4])
            if pid == os.getpid():
                return f"this process (pid {pid})"
            return _process(pid)
    return None


def _process(pid: int) -> str:
    """'pid N (command line)'; a multiprocessing child (a reader process) is named through its
    parent, the program the user started."""
    command = _command(pid)
    if command and "multiprocessing" in command:
        parent = _parent(pid)
        if parent:
            return f"pid {parent} ({_command(parent) or '?'}), through its reader process {pid}"
    return f"pid {pid} ({command or '?'})"


def _command(pid: int) -> str | None:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            args = fh.read().split(b"\0")
    except OSError:
        return None
    words = [a.decode(errors="replace") for a in args if a]
    if len(words) > 1 and os.path.basename(words[0]).startswith("python") and "puppet" in words[1]:
        words = [os.path.basename(words[1])] + words[2:]  # python .../bin/puppet live ...
    elif words:
        words[0] = os.path.basename(words[0])
    return " ".join(words) or None


def _parent(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("PPid:"):
                    return int(line.split()[1]) or None
    except OSError:
        return None
    return None
