"""hw_sim: a simulated Dynamixel bus on a pseudo-terminal, Protocol 2.0 or Protocol 1.0.

The real ``dynamixel_sdk`` opens the bus's port path like a serial port. This package
imports nothing from ``puppet``.

Models (``hw_sim.control_table.MODEL_SPECS``, the same table as ``puppet.servo_models``):
X-series (XL330, XC330, XL430, 2XL430, XC430, XM430, XH430, XM540), MX-28(2.0), MX-64(2.0),
MX-106(2.0) and the XL-320 (its own table: Present Position at 37, 2 bytes) on Protocol 2.0;
AX-12A, AX-12W, AX-18A, RX-24F, RX-28, RX-64, MX-12W, MX-28, MX-64, MX-106 on Protocol 1.0
(PING, READ, WRITE, REG_WRITE / ACTION, RESET, SYNC_WRITE, BULK_READ on MX; status error bits:
input voltage, angle limit, overheating, range, checksum, overload, instruction). One bus
carries one protocol: ``serve`` refuses servos of both, naming them (open the port with
``dynamixel_sdk.PacketHandler(1.0)`` for a Protocol 1.0 bus). Every fault kind works on both.

In-process API (tests, demos)::

    from hw_sim import serve
    with serve(range(1, 4), motion="wave") as bus:          # or {id: "XL430-W250", ...}, {1: "AX-12A"}
        port = dynamixel_sdk.PortHandler(bus.port)          # bus.port: '/dev/pts/N'
        port.openPort(); port.setBaudRate(1_000_000)
        ...
        bus.inject("drop", ids=[2], duration_s=0.5)          # immediate fault
        bus.clear_faults()
        bus.set_positions({1: 5000})                         # programmatic motion (torque off)
        assert bus.servo(1).get("Present Position") == 5000  # control table, for assertions

``serve(servos, *, model="XL330-M288", motion=None, faults=None, timing=False, baud=1_000_000,
return_delay_us=None, echo=False, strict_baud=False, process=True, seed=0)`` yields a
``SimBus``: ``port`` (current pty path; None while unplugged, a new path after a replug),
``link`` (a stable symlink to the current pty that works again after a replug, like
/dev/serial/by-id), ``inject(kind, ids=None, *, duration_s=None, **params)``,
``clear_faults()``, ``set_positions({id: counts})``, ``servo(id) -> ServoView``
(``get(name)``, ``set(name, value)``, ``read(addr, size)``, ``powered``, ``model``,
``hardware_error``), ``traffic()`` (bytes seen, both ways) and ``counts()``.

Fault kinds (see ``hw_sim.faults``): drop, bad_crc, truncate, error_status, power_cycle,
power_off, power_on, unplug, replug, duplicate_id, hardware_error, noise, echo. An unplug closes
the pty's master: an SDK call waiting for a reply raises ``serial.SerialException`` ("device
reports readiness to read but returned no data") and leaves ``port.is_using`` True (later calls
return COMM_PORT_BUSY); an SDK call started after the unplug fails in ``clearPort()`` with
``termios.error`` (EIO), as on a hung-up USB tty.

The bus server runs in a forked child process (the SDK busy-polls while holding the GIL, so a
responder thread in the same process would compete with it); ``SimBus`` talks to it over a pipe.
Pass ``process=False`` to run it in a thread instead.

Modules: ``codec`` (Protocol 2.0 packet bytes, CRC-16, stuffing, device-side parser),
``codec1`` (Protocol 1.0: checksum, parser, status packets, error bits), ``control_table``
(every model's table as data), ``servo`` (one servo's state and behaviour, any layout),
``device_bus`` (instruction dispatch for the servos on a bus, either protocol), ``motion`` (motion sources), ``faults`` (fault
kinds, schedules, the fault file), ``server`` (the pty server, ``serve`` and ``SimBus``),
``cli`` (``hw-sim``).
"""

from hw_sim.errors import FaultFileError, HwSimError, MotionFileError
from hw_sim.faults import Fault, FaultError, FaultSchedule
from hw_sim.server import ServoView, SimBus, serve

__version__ = "0.1.0"

__all__ = ["serve", "SimBus", "ServoView", "Fault", "FaultSchedule", "HwSimError", "FaultError",
           "MotionFileError", "FaultFileError"]
