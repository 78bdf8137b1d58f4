"""The on-disk layout of a take: MCAP records, names and the message encoding of a Reading.

A take is an MCAP file (https://mcap.dev) written without chunks, so every record lands in the
file as soon as it is written (crash safety):

  Header                      profile "", library "puppet/<version>"
  Metadata "puppet.take"      format_version, rig_name, ids (JSON list), models (JSON object
                              id -> model name), servo_count, created_unix_ns
  Metadata "puppet.rig_map"   text: the rig map TOML the take was recorded with
  Metadata "puppet.calibration" text: the calibration text the take was recorded with
  Metadata "puppet.sound"     optional: the sound performed to (puppet.take.sync)
  Metadata "puppet.timecode"  optional: the start timecode (puppet.take.sync)
  Schema   "puppet_msgs/msg/ServoReading" (encoding ros2msg, text below)
  Channel  "/puppet/servo_readings" (message encoding cdr; metadata: ids)
  Message* one per Reading, log_time = publish_time = t_ns
  Channel/Message "/puppet/markers"  optional: named time marks (puppet.take.markers)
  Channel/Message "/puppet/keys"     optional: a shot's key poses (puppet.take.keys)
  DataEnd, summary, Footer    only when the writer was closed cleanly

Message payload: XCDR1 little endian of the ros2msg schema, which for this schema is a fixed
layout (every field is naturally aligned), k = number of servos:

  offset 0        4 bytes  encapsulation header 00 01 00 00 (CDR_LE)
  offset 4        int64    t_ns
  offset 12       uint32   k
  offset 16       int32[k] ticks
  offset 16+4k    uint32   k
  offset 20+4k    uint8[k] ok (0 or 1)
  version 1 ends here: 20+5k bytes
  offset 20+5k    p bytes  zero padding to 4-byte alignment, p = (-k) mod 4
  offset 20+5k+p  uint32   crc: CRC-32 (zlib.crc32) of payload bytes [0, 20+5k+p)
  version 2 total 24+5k+p bytes
  version 3: the layout of version 2; each ok byte is 1 (read), 0 (failed: a fault) or 2 (late:
  the value held only because the reply came late on a busy host, ``Reading.late``, not a fault)

Versions 1 and 2 did not keep why a read failed: their readings come back with late None (every
servo not ok counts as at fault).

Every reading of a take has the same size, so a reader that meets a damaged record finds the
next one (see puppet.take.reader). Version 2 also protects the metadata: the "puppet.take"
record holds rig_map_crc32 and calibration_crc32 (CRC-32 of the texts, 8 hex digits) and crc32,
the checksum of its own other entries (see info_checksum).

Robotics tools that read ros2msg/cdr (e.g. Foxglove) can plot ticks and ok directly.
"""

from __future__ import annotations

import zlib

import numpy as np

FORMAT_VERSION = 3
READABLE_VERSIONS = (1, 2, 3)

TAKE_METADATA = "puppet.take"
RIG_MAP_METADATA = "puppet.rig_map"
CALIBRATION_METADATA = "puppet.calibration"

SCHEMA_NAME = "puppet_msgs/msg/ServoReading"
SCHEMA_ENCODING = "ros2msg"
SCHEMA_TEXT_V1 = (
    "# One group read of every servo of a puppet rig (Present Position, raw encoder ticks).\n"
    "int64 t_ns      # monotonic clock of the read, nanoseconds\n"
    "int32[] ticks   # signed continuous encoder counts, 4096 per turn, in the take's ids order\n"
    "bool[] ok       # false where the read failed for that servo (ticks then hold the last good value)\n"
)
SCHEMA_TEXT = SCHEMA_TEXT_V1 + (
    "uint32 crc      # CRC-32 (zlib) of every payload byte before this field\n"
)
SCHEMA_TEXT_V2 = SCHEMA_TEXT
SCHEMA_TEXT = (
    "# One group read of every servo of a puppet rig (Present Position, raw encoder ticks).\n"
    "int64 t_ns      # monotonic clock of the read, nanoseconds\n"
    "int32[] ticks   # signed continuous encoder counts, 4096 per turn, in the take's ids order\n"
    "uint8[] ok      # 1 read; 0 failed, a fault (ticks hold the last good value); 2 late, held only "
    "because the reply came late (not a fault)\n"
    "uint32 crc      # CRC-32 (zlib) of every payload byte before this field\n"
)
SCHEMA_TEXTS = {1: SCHEMA_TEXT_V1, 2: SCHEMA_TEXT_V2, 3: SCHEMA_TEXT}
OK_BYTE_LATE = 2
"""Version 3: an ok byte that says the servo's value is held because its reply came late."""
MESSAGE_ENCODING = "cdr"
TOPIC = "/puppet/servo_readings"

CDR_LE_HEADER = b"\x00\x01\x00\x00"


def crc_offset(k: int) -> int:
    """Payload offset of a version-2 reading's crc field (k servos)."""
    return 20 + 5 * k + (-k) % 4


def message_size(k: int, version: int = FORMAT_VERSION) -> int:
    """Bytes of one encoded Reading of k servos in take format ``version``."""
    return 20 + 5 * k if version == 1 else crc_offset(k) + 4


def text_checksum(text: str) -> str:
    """CRC-32 of a metadata text (UTF-8), as the 8 hex digits stored in the take."""
    return f"{zlib.crc32(text.encode('utf-8')):08x}"


def info_checksum(info: dict[str, str]) -> str:
    """CRC-32 of the "puppet.take" entries other than crc32 itself (sorted key=value lines)."""
    lines = "\n".join(f"{key}={info[key]}" for key in sorted(info) if key != "crc32")
    return text_checksum(lines)


class ReadingCodec:
    """Encodes Readings of k servos into one reused buffer, and checks and decodes payloads.

    version: take format version (1: no checksum; 2: crc field, see the module docstring).
    buffer:  bytearray of message_size(k, version) bytes, rewritten in place by encode().
    """

    def __init__(self, k: int, version: int = FORMAT_VERSION):
        if version not in READABLE_VERSIONS:
            raise ValueError(f"ReadingCodec: take format version {version} is not one of "
                             f"{READABLE_VERSIONS}")
        self.k = int(k)
        self.version = int(version)
        self.size = message_size(self.k, self.version)
        self.crc_at = crc_offset(self.k) if self.version >= 2 else None
        self.buffer = bytearray(self.size)
        self.buffer[0:4] = CDR_LE_HEADER
        self.buffer[12:16] = np.uint32(self.k).tobytes()
        self.buffer[16 + 4 * self.k : 20 + 4 * self.k] = np.uint32(self.k).tobytes()
        self._view = memoryview(self.buffer)
        self._t = np.frombuffer(self.buffer, dtype="<i8", count=1, offset=4)
        self._ticks = np.frombuffer(self.buffer, dtype="<i4", count=self.k, offset=16)
        self._ok = np.frombuffer(self.buffer, dtype=np.uint8, count=self.k, offset=20 + 4 * self.k)
        if self.crc_at is not None:
            self._crc = np.frombuffer(self.buffer, dtype="<u4", count=1, offset=self.crc_at)

    def encode(self, t_ns: int, ticks: np.ndarray, ok: np.ndarray,
               late: np.ndarray | None = None) -> bytearray:
        """Write one reading into self.buffer and return it (valid until the next call).

        ticks: (k,) integer encoder counts; ok: (k,) bool; late: None or (k,) bool, True where
        a servo not ok is only late (``Reading.late``; kept from version 3 on). Allocates nothing.
        """
        self._t[0] = t_ns
        self._ticks[:] = ticks
        self._ok[:] = ok
        if late is not None and self.version >= 3:
            np.copyto(self._ok, OK_BYTE_LATE, where=late)  # never where ok (Reading.late)
        if self.crc_at is not None:
            self._crc[0] = zlib.crc32(self._view[: self.crc_at])
        return self.buffer

    def check(self, payload) -> tuple[str, str] | None:
        """None when payload is a well-formed reading of k servos, else (reason, detail).

        reason is "checksum mismatch" (version 2) or "malformed reading".
        """
        if len(payload) != self.size:
            return "malformed reading", f"{len(payload)} bytes, expected {self.size} for {self.k} servos"
        if self.crc_at is not None:
            stored = int.from_bytes(payload[self.crc_at : self.crc_at + 4], "little")
            actual = zlib.crc32(memoryview(payload)[: self.crc_at])
            if stored != actual:
                return "checksum mismatch", f"crc {stored:08x}, payload gives {actual:08x}"
        if bytes(payload[0:4]) != CDR_LE_HEADER:
            return ("malformed reading",
                    f"encapsulation header {bytes(payload[0:4]).hex()}, expected 00010000")
        n1 = int.from_bytes(payload[12:16], "little")
        n2 = int.from_bytes(payload[16 + 4 * self.k : 20 + 4 * self.k], "little")
        if n1 != self.k or n2 != self.k:
            return "malformed reading", f"sequence lengths {n1}/{n2}, expected {self.k}"
        if self.version >= 3:
            at = 20 + 4 * self.k
            worst = max(payload[at : at + self.k], default=0)
            if worst > OK_BYTE_LATE:
                return "malformed reading", f"ok byte {worst}, expected 0, 1 or {OK_BYTE_LATE}"
        return None

    def decode(self, payload) -> tuple[int, np.ndarray, np.ndarray, np.ndarray | None]:
        """(t_ns, ticks (k,) int32, ok (k,) bool, late (k,) bool or None before version 3),
        fresh arrays, from a checked payload."""
        t_ns = int(np.frombuffer(payload, dtype="<i8", count=1, offset=4)[0])
        ticks = np.frombuffer(payload, dtype="<i4", count=self.k, offset=16).astype(np.int32)
        ok, late = self.ok_late(np.frombuffer(payload, dtype=np.uint8, count=self.k,
                                              offset=20 + 4 * self.k))
        return t_ns, ticks, ok, late

    def ok_late(self, ok_bytes: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(ok, late) bool arrays of the shape of ``ok_bytes`` (the payloads' ok bytes); late
        None before version 3 (the reason was not kept)."""
        if self.version < 3:
            return ok_bytes != 0, None
        return ok_bytes == 1, ok_bytes == OK_BYTE_LATE

    @staticmethod
    def t_ns_of(payload) -> int:
        """The t_ns field of a payload (any version)."""
        return int.from_bytes(payload[4:12], "little", signed=True)
