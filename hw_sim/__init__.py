"""hw_sim: a simulated Dynamixel Protocol 2.0 bus on a pseudo-terminal.

The real ``dynamixel_sdk`` opens the bus's port path like a serial port. This package
imports nothing from ``puppet``.

In-process API (tests, demos)::

    from hw_sim import serve
    with serve(range(1, 4), motion="wave") as bus:
        port = dynamixel_sdk.PortHandler(bus.port)      # bus.port: '/dev/pts/N'
        port.openPort(); port.setBaudRate(1_000_000)
        ...
        bus.inject("drop", ids=[2], duration_s=0.5)      # immediate fault
        bus.set_positions({1: 5000})                     # programmatic motion (torque off)
        assert bus.servo(1).read_field("Present Position") == 5000

The bus server runs in a forked child process (the SDK busy-polls while holding the GIL, so a
responder thread in the same process would compete with it); ``SimBus`` talks to it over a pipe.
Pass ``process=False`` to run it in a thread instead.

Modules: ``codec`` (packet bytes, CRC-16, stuffing, device-side parser), ``control_table``
(X-series tables as data), ``servo`` (one servo's state and behaviour), ``device_bus``
(instruction dispatch for a set of servos), ``motion`` (motion sources), ``faults`` (fault kinds
and schedules), ``server`` (the pty server, ``serve`` and ``SimBus``), ``cli`` (``hw-sim``).
"""

from hw_sim.server import SimBus, ServoView, serve
from hw_sim.errors import HwSimError, MotionFileError, FaultFileError

__version__ = "0.1.0"

__all__ = ["serve", "SimBus", "ServoView", "HwSimError", "MotionFileError", "FaultFileError"]
