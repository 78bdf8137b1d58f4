"""Servo IO through dynamixel_sdk: scan, configure, group reads, recovery.

Public API:
    ServoReader(port, {id: model}, baud=..., read_mode=..., actuators=..., limits=...)
        .open(broadcast_ping=False, strict=False) -> SetupReport
        .read() -> Reading;  .read_clean(samples, timeout_s) -> Reading
        .health {id: ServoHealth};  .log (EventLog of BusEvent);  .reboot(id);  .write_goals({id: ticks})
    ReaderThread(reader, rate_hz, queue_len): .start() .latest() .drain() .call(fn) .set_goals() .stop()
    Reading(t_ns, ids, ticks int32, ok bool)
    errors: BusError > PortError, ServoError > ServoTimeout, ServoCorrupt, ServoStatusError,
            ServoModelMismatch, ServoMissing
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
from puppet.bus.health import BusEvent, ServoHealth
from puppet.bus.link import BusLink, set_latency_assumption
from puppet.bus.reader import ServoReader
from puppet.bus.reader_thread import LatestQueue, ReaderDied, ReaderThread
from puppet.bus.reading import Reading

__all__ = [
    "Reading", "ServoReader", "ReaderThread", "LatestQueue", "ReaderDied", "BusLink",
    "set_latency_assumption", "SetupReport", "Change", "ServoHealth", "BusEvent",
    "BusError", "PortError", "ServoError", "ServoTimeout", "ServoCorrupt", "ServoStatusError",
    "ServoModelMismatch", "ServoMissing",
]
