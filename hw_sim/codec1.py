"""Device-side Protocol 1.0 codec: checksum, instruction parsing, status building, error bits.

Wire format (instruction): ``FF FF ID LEN INST P1..Pn CHK``, LEN = n + 2. Status:
``FF FF ID LEN ERR P1..Pn CHK``. CHK = ``~(ID + LEN + INST/ERR + ΣP) & 0xFF``. No stuffing, no
reserved byte; ids 0..253, 0xFE broadcast (no status for a broadcast, except Bulk Read's).
Parameters: READ ``addr len``; WRITE / REG_WRITE ``addr data..``; SYNC_WRITE ``addr len (id
data..)*``; BULK_READ (MX only) ``00 (len id addr)*``; RESET none. There is no Sync Read and no
Reboot. ERR is a bit field (bit 7 always 0): 0x01 input voltage, 0x02 angle limit, 0x04
overheating, 0x08 range, 0x10 checksum, 0x20 overload, 0x40 instruction.

The servos answer in Protocol 2.0 error numbers (``hw_sim.codec``); ``error_byte`` turns one,
with the servo's hardware error bits (which sit at the same bit positions as Protocol 1.0's
voltage, overheating and overload bits), into the Protocol 1.0 error byte.
"""

from __future__ import annotations

from hw_sim import codec
from hw_sim.codec import Instruction

PROTOCOL = 1.0
HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
MAX_ID = 0xFD

# Instruction codes (the same numbers as Protocol 2.0's where both have one).
PING, READ, WRITE, REG_WRITE, ACTION, RESET = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
SYNC_WRITE, BULK_READ = 0x83, 0x92

# Status error bits.
ERR_VOLTAGE, ERR_ANGLE, ERR_OVERHEAT, ERR_RANGE = 0x01, 0x02, 0x04, 0x08
ERR_CHECKSUM, ERR_OVERLOAD, ERR_INSTRUCTION = 0x10, 0x20, 0x40
HARDWARE_BITS = ERR_VOLTAGE | ERR_OVERHEAT | ERR_OVERLOAD
"""Hardware Error Status bits that Protocol 1.0 reports, at the same positions."""

_FROM_P2 = {0: 0, codec.ERR_RESULT_FAIL: ERR_RANGE, codec.ERR_INSTRUCTION: ERR_INSTRUCTION,
            codec.ERR_CRC: ERR_CHECKSUM, codec.ERR_DATA_RANGE: ERR_RANGE,
            codec.ERR_DATA_LENGTH: ERR_RANGE, codec.ERR_DATA_LIMIT: ERR_ANGLE,
            codec.ERR_ACCESS: ERR_RANGE}
"""Protocol 2.0 error number -> Protocol 1.0 bit: a Goal Position outside the angle limits is
the angle limit error; a write the table refuses (read-only, locked EEPROM, out of range, a
partial item) the range error."""


def checksum(body: bytes | bytearray) -> int:
    """``~sum & 0xFF`` of ID, LEN, INST/ERR and parameters."""
    return ~sum(body) & 0xFF


def packet(dxl_id: int, inst: int, params: bytes | bytearray = b"") -> bytes:
    """A complete instruction packet (host side; tests and the echo fault)."""
    body = bytes((dxl_id, len(params) + 2, inst)) + bytes(params)
    return HEADER + body + bytes((checksum(body),))


def status_packet(dxl_id: int, error: int, params: bytes | bytearray = b"") -> bytes:
    """A complete status packet ``FF FF ID LEN ERR params CHK`` (error: the P1 bit field)."""
    body = bytes((dxl_id, len(params) + 2, error & 0x7F)) + bytes(params)
    return HEADER + body + bytes((checksum(body),))


def error_byte(number: int, hardware_error: int) -> int:
    """The status error byte for a Protocol 2.0 error number and Hardware Error Status bits."""
    return _FROM_P2.get(number, ERR_RANGE) | (hardware_error & HARDWARE_BITS)


class InstructionParser:
    """Incremental device-side parser: feed bytes, get complete instruction packets.

    Like servo firmware it looks for ``FF FF``, takes the next byte as the id (another ``FF``
    shifts the header along), reads LEN, and skips one byte at a time past an impossible LEN.
    A packet with a wrong checksum is returned with ``crc_ok`` False (the servo answers with
    the checksum error bit). ``reset()`` drops a partial packet (inter-byte gap exceeded).
    """

    def __init__(self) -> None:
        self._buf = bytearray()

    def reset(self) -> None:
        self._buf.clear()

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[Instruction]:
        buf = self._buf
        buf += data
        out: list[Instruction] = []
        while True:
            idx = buf.find(HEADER)
            if idx < 0:
                del buf[: len(buf) - (1 if buf.endswith(b"\xff") else 0)]
                return out
            if idx:
                del buf[:idx]
            if len(buf) < 4:
                return out
            if buf[2] == 0xFF:  # FF FF FF: the header starts one byte later
                del buf[:1]
                continue
            length = buf[3]
            if length < 2:
                del buf[:1]
                continue
            total = 4 + length
            if len(buf) < total:
                return out
            pkt = bytes(buf[:total])
            del buf[:total]
            ok = checksum(pkt[2:-1]) == pkt[-1]
            out.append(Instruction(pkt[2], pkt[4], pkt[5:-1], total, ok))
