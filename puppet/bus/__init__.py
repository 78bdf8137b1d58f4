"""Servo IO through dynamixel_sdk: scan, configure, group reads, recovery, on a bus of Protocol
2.0 (X-series, MX(2.0), XL-320) or Protocol 1.0 (AX, RX, MX): one protocol per bus, each
servo's items from its model (``puppet.servo_models``). Imports nothing of puppet.drive:
servos that move plug into the reader process's cycle hook.

Public API:
    ServoReader(port | PortHandler, {id: model}, baud=..., latency_ms=None, read_mode="auto",
                driven=(), limits=None, auto_reboot=True, ...)
        .open(broadcast_ping=False, strict=False) -> SetupReport (found, missing, unexpected,
              changes, hardware_errors, read_mode)
        .read() -> Reading (never raises for bus faults);  .read_clean(samples, timeout_s) -> Reading
        .health {id: ServoHealth};  .log (EventLog of BusEvent: .events, .counts, .drain())
        .reboot(id);  .group;  .port_up;  .close()
    ReaderThread(reader, rate_hz, queue_len): .start() .latest() .drain() .call(fn) .stop()
    ReaderProcess(port, {id: model}, rate_hz, hook=CycleHook) (puppet.bus.reader_process): the
        reader in a child process; a hook (puppet.drive plugs in) writes goals each cycle
    BusLink(port, baud, latency_ms, protocol=2.0): the SDK with its crash paths absorbed (ping,
        read, write, group_read, sync_read, fast_sync_read, bulk_read (1.0), sync_write,
        reboot (2.0), broadcast_ping, ping_each, rebuild)
    scan(port, bauds, protocols) (puppet.bus.scan): every servo answering at each baud and
        protocol -> [Found(baud, protocol, id, number, firmware)]
    Reading(t_ns, ids, ticks int32, ok bool)
    errors: BusError > PortError > PortInUse (port_lock: one program per port),
            ServoError > ServoTimeout, ServoCorrupt, ServoStatusError, ServoModelMismatch,
            ServoMissing
"""

from puppet.bus.configure import Change, SetupReport
from puppet.bus.errors import (
    BusError,
    PortError,
    ServoCorrupt,
    ServoError,
    ServoMissing,
    ServoModelMismatch,
    ServoStatusError,
    ServoTimeout,
)
from puppet.bus.health import ServoHealth
from puppet.bus.latency import set_latency_assumption
from puppet.bus.link import BusLink
from puppet.bus.port_lock import PortInUse
from puppet.bus.reader import ServoReader
from puppet.bus.reader_thread import LatestQueue, ReaderDied, ReaderThread
from puppet.events import BusEvent, EventLog
from puppet.reading import Reading

__all__ = [
    "Reading", "ServoReader", "ReaderThread", "LatestQueue", "ReaderDied", "BusLink",
    "set_latency_assumption", "SetupReport", "Change", "ServoHealth", "BusEvent", "EventLog",
    "BusError", "PortError", "PortInUse", "ServoError", "ServoTimeout", "ServoCorrupt", "ServoStatusError",
    "ServoModelMismatch", "ServoMissing",
]
