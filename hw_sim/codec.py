"""Device-side Protocol 2.0 codec: CRC-16, byte stuffing, instruction parsing, status building.

Wire format (instruction): ``FF FF FD 00 ID LEN_L LEN_H INST P1..Pn CRC_L CRC_H``, LEN = n + 3,
counted after stuffing. Status: ``FF FF FD 00 ID LEN_L LEN_H 55 ERR P1..Pn CRC_L CRC_H``,
LEN = n + 4. CRC-16/BUYPASS (poly 0x8005, init 0, no reflection) over every byte from the
header to the last parameter, sent low byte first. Stuffing: after every ``FF FF FD`` in
INST..params insert ``FD``.
"""

from __future__ import annotations

from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
STATUS = 0x55
MAX_ID = 0xFC

# Instruction codes.
PING, READ, WRITE, REG_WRITE, ACTION, FACTORY_RESET, REBOOT, CLEAR, BACKUP = (
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x08, 0x10, 0x20)
SYNC_READ, SYNC_WRITE, FAST_SYNC_READ = 0x82, 0x83, 0x8A
BULK_READ, BULK_WRITE, FAST_BULK_READ = 0x92, 0x93, 0x9A

# Error numbers (bits 6..0 of the status ERR byte); bit 7 is the alert bit.
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE = 0x01, 0x02, 0x03, 0x04
ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = 0x05, 0x06, 0x07
ALERT = 0x80


def _make_crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


CRC_TABLE = _make_crc_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16/BUYPASS of ``data``, continuing from ``crc`` (0 to start)."""
    table = CRC_TABLE
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[((crc >> 8) ^ b) & 0xFF]
    return crc


def stuff(body: bytes | bytearray) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` in ``body`` (INST..last param)."""
    if b"\xff\xff\xfd" not in body:
        return bytes(body)
    return bytes(body).replace(b"\xff\xff\xfd", b"\xff\xff\xfd\xfd")


def unstuff(body: bytes | bytearray) -> bytes:
    """Remove the stuffing ``FD`` after every ``FF FF FD``."""
    if b"\xff\xff\xfd\xfd" not in body:
        return bytes(body)
    return bytes(body).replace(b"\xff\xff\xfd\xfd", b"\xff\xff\xfd")


def packet(dxl_id: int, inst: int, params: bytes | bytearray = b"") -> bytes:
    """A complete, stuffed instruction packet (host side; used by tests and the echo fault)."""
    body = stuff(bytes([inst]) + bytes(params))
    head = HEADER + bytes([dxl_id, (len(body) + 2) & 0xFF, (len(body) + 2) >> 8])
    out = head + body
    crc = crc16(out)
    return out + bytes([crc & 0xFF, crc >> 8])


def status_packet(dxl_id: int, error: int, params: bytes | bytearray = b"") -> bytes:
    """A complete, stuffed status packet: ``FF FF FD 00 ID LEN 55 ERR params CRC``."""
    body = stuff(bytes((STATUS, error)) + bytes(params))
    n = len(body) + 2
    out = HEADER + bytes((dxl_id, n & 0xFF, n >> 8)) + body
    crc = crc16(out)
    return out + bytes((crc & 0xFF, crc >> 8))


def fast_status_packet(segments: list[tuple[int, int, bytes]]) -> bytes:
    """One Fast Sync/Bulk Read reply from ID 0xFE, not stuffed.

    segments: ``[(error, id, data), ...]`` in the order the ids were listed. Each segment is
    ``ERR ID data CRC``, where CRC is the running CRC-16 of every byte sent before it (the last
    one is the packet CRC). LEN = 1 + sum(len(data) + 4).
    """
    # LEN counts INST + segments (ERR, ID, data, CRC each); the last segment's CRC is the
    # packet CRC, so there is no extra trailing CRC.
    n = 1 + sum(len(d) + 4 for _, _, d in segments)
    out = bytearray(HEADER + bytes((BROADCAST_ID, n & 0xFF, n >> 8, STATUS)))
    crc = crc16(out)
    for err, dxl_id, data in segments:
        seg = bytes((err, dxl_id)) + bytes(data)
        out += seg
        crc = crc16(seg, crc)
        out += bytes((crc & 0xFF, crc >> 8))
        crc = crc16(bytes((crc & 0xFF, crc >> 8)), crc)
    return bytes(out)


@dataclass(frozen=True)
class Instruction:
    """A decoded instruction packet.

    dxl_id: target id (0xFE broadcast); inst: instruction code; params: unstuffed parameters;
    raw_len: bytes it took on the wire (for the timing model); crc_ok: False when the CRC was
    wrong (the packet is reported so the bus can decide to stay silent).
    """

    dxl_id: int
    inst: int
    params: bytes
    raw_len: int
    crc_ok: bool = True


class InstructionParser:
    """Incremental device-side parser: feed bytes, get complete instruction packets.

    Like servo firmware it searches for ``FF FF FD`` not followed by ``FD``, skips garbage, and
    reads LEN. Packets with a bad reserved byte or an impossible LEN are skipped one byte at a
    time. ``max_gap_s`` (1.5 ms on the wire) is enforced by the caller via ``reset()``.
    """

    MAX_LEN = 1024 + 10

    def __init__(self) -> None:
        self._buf = bytearray()

    def reset(self) -> None:
        """Discard a partial packet (inter-byte gap exceeded)."""
        self._buf.clear()

    @property
    def pending(self) -> int:
        """Bytes held of an incomplete packet."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Instruction]:
        buf = self._buf
        buf += data
        out: list[Instruction] = []
        while True:
            idx = buf.find(b"\xff\xff\xfd")
            if idx < 0:
                # Keep a possible partial header at the end.
                keep = 2 if buf.endswith(b"\xff\xff") else (1 if buf.endswith(b"\xff") else 0)
                del buf[: len(buf) - keep]
                return out
            if idx:
                del buf[:idx]
            if len(buf) < 7:
                return out
            if buf[3] != 0x00 or buf[4] in (0xFD, 0xFF):
                # FF FF FD FD (stuffed data) or a bad reserved byte / id: not a header.
                del buf[:1]
                continue
            length = buf[5] | (buf[6] << 8)
            if length < 3 or length > self.MAX_LEN:
                del buf[:1]
                continue
            total = 7 + length
            if len(buf) < total:
                return out
            pkt = bytes(buf[:total])
            del buf[:total]
            crc = crc16(pkt[:-2])
            crc_ok = (pkt[-2] | (pkt[-1] << 8)) == crc
            out.append(Instruction(pkt[4], pkt[7], unstuff(pkt[8:-2]), total, crc_ok))


PROTOCOL = 2.0


def error_byte(number: int, hardware_error: int) -> int:
    """The status error byte: the error number, with the alert bit while a hardware error is
    latched (the servo's Hardware Error Status bits)."""
    return number | (ALERT if hardware_error else 0)
