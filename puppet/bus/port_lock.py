"""One program per port: an exclusive advisory lock (``flock``) on the opened serial device.

Two programs on one bus undo each other (one turns torque on for the other's sensors, off
for its actuators, clears its watchdog). ``BusLink.open`` locks the device it opened, without
waiting (a pseudo-terminal such as hw_sim's too); when another process holds it, ``PortInUse``
names that process: pid and command line, from ``/proc/locks`` (``puppet.lock_holder``; Linux;
elsewhere the error says only that the port is in use). The lock belongs to the open file:
closing the port, or the process dying (even by SIGKILL), releases it.
"""

from __future__ import annotations

import fcntl

from puppet.bus.errors import PortError
from puppet.lock_holder import holder


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
