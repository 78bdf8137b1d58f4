"""Who holds a lock: the process holding a ``flock`` on a file, in words (pid and command line).

Used wherever one program at a time is the rule and a refusal must name the other program: a
serial port (``puppet.bus.port_lock``), a session folder (``puppet.studio.lock``). The holder
is found in ``/proc/locks`` (Linux; elsewhere None: the caller says only that it is in use).
"""

from __future__ import annotations

import os


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
            return process(pid)
    return None


def process(pid: int) -> str:
    """'pid N (command line)'; a multiprocessing child (a reader process) is named through its
    parent, the program the user started."""
    line = command(pid)
    if line and "multiprocessing" in line:
        parent = _parent(pid)
        if parent:
            return f"pid {parent} ({command(parent) or '?'}), through its reader process {pid}"
    return f"pid {pid} ({line or '?'})"


def command(pid: int) -> str | None:
    """The command line of process ``pid`` as a user typed it ('puppet live --rig r.toml'), or
    None when it cannot be read (gone, another OS)."""
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
