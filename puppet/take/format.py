"""The on-disk layout of a take: MCAP records, names and the message encoding of a Reading.

A take is an MCAP file (https://mcap.dev) written without chunks, so every record lands in the
file as soon as it is written (crash safety):

  Header                      profile "", library "puppet/<version>"
  Metadata "puppet.take"      format_version, rig_name, ids (JSON list), models (JSON object
                              id -> model name), servo_count, created_unix_ns
  Metadata "puppet.rig_map"   text: the rig map TOML the take was recorded with
  Metadata "puppet.calibration" text: the calibration text the take was recorded with
  Schema   "puppet_msgs/msg/ServoReading" (encoding ros2msg, text below)
  Channel  "/puppet/servo_readings" (message encoding cdr; metadata: ids)
  Message* one per Reading, log_time = publish_time = t_ns
  DataEnd, summary, Footer    only when the writer was closed cleanly

Message payload: XCDR1 little endian of the ros2msg schema, which for this schema is a fixed
layout (every field is naturally aligned), k = number of servos:

  offset 0        4 bytes  encapsulation header 00 01 00 00 (CDR_LE)
  offset 4        int64    t_ns
  offset 12       uint32   k
  offset 16       int32[k] ticks
  offset 16+4k    uint32   k
  offset 20+4k    uint8[k] ok (0 or 1)
  total           20+5k bytes

Robotics tools that read ros2msg/cdr (e.g. Foxglove) can plot ticks and ok directly.
"""

from __future__ import annotations

import numpy as np

FORMAT_VERSION = 1

TAKE_METADATA = "puppet.take"
RIG_MAP_METADATA = "puppet.rig_map"
CALIBRATION_METADATA = "puppet.calibration"

SCHEMA_NAME = "puppet_msgs/msg/ServoReading"
SCHEMA_ENCODING = "ros2msg"
SCHEMA_TEXT = (
    "# One group read of every servo of a puppet rig (Present Position, raw encoder ticks).\n"
    "int64 t_ns      # monotonic clock of the read, nanoseconds\n"
    "int32[] ticks   # signed continuous encoder counts, 4096 per turn, in the take's ids order\n"
    "bool[] ok       # false where the read failed for that servo (ticks then hold the last good value)\n"
)
MESSAGE_ENCODING = "cdr"
TOPIC = "/puppet/servo_readings"

CDR_LE_HEADER = b"\x00\x01\x00\x00"


def message_size(k: int) -> int:
    """Bytes of one encoded Reading of k servos."""
    return 20 + 5 * k


class ReadingCodec:
    """Encodes Readings of k servos into one reused buffer, and decodes payloads.

    buffer: bytearray of message_size(k) bytes, rewritten in place by encode().
    """

    def __init__(self, k: int):
        self.k = int(k)
        self.size = message_size(self.k)
        self.buffer = bytearray(self.size)
        self.buffer[0:4] = CDR_LE_HEADER
        self.buffer[12:16] = np.uint32(self.k).tobytes()
        self.buffer[16 + 4 * self.k : 20 + 4 * self.k] = np.uint32(self.k).tobytes()
        self._t = np.frombuffer(self.buffer, dtype="<i8", count=1, offset=4)
        self._ticks = np.frombuffer(self.buffer, dtype="<i4", count=self.k, offset=16)
        self._ok = np.frombuffer(self.buffer, dtype=np.uint8, count=self.k, offset=20 + 4 * self.k)

    def encode(self, t_ns: int, ticks: np.ndarray, ok: np.ndarray) -> bytearray:
        """Write one reading into self.buffer and return it (valid until the next call).

        ticks: (k,) integer encoder counts; ok: (k,) bool.
        """
        self._t[0] = t_ns
        self._ticks[:] = ticks
        self._ok[:] = ok
        return self.buffer

    def check(self, payload) -> str | None:
        """None when payload is a well-formed reading of k servos, else what is wrong."""
        if len(payload) != self.size:
            return f"{len(payload)} bytes, expected {self.size} for {self.k} servos"
        if bytes(payload[0:4]) != CDR_LE_HEADER:
            return f"encapsulation header {bytes(payload[0:4]).hex()}, expected 00010000"
        n1 = int.from_bytes(payload[12:16], "little")
        n2 = int.from_bytes(payload[16 + 4 * self.k : 20 + 4 * self.k], "little")
        if n1 != self.k or n2 != self.k:
            return f"sequence lengths {n1}/{n2}, expected {self.k}"
        return None

    def decode(self, payload) -> tuple[int, np.ndarray, np.ndarray]:
        """(t_ns, ticks (k,) int32, ok (k,) bool), fresh arrays, from a checked payload."""
        t_ns = int(np.frombuffer(payload, dtype="<i8", count=1, offset=4)[0])
        ticks = np.frombuffer(payload, dtype="<i4", count=self.k, offset=16).astype(np.int32)
        ok = np.frombuffer(payload, dtype=np.uint8, count=self.k, offset=20 + 4 * self.k) != 0
        return t_ns, ticks, ok
