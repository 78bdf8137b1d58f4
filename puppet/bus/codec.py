"""The Dynamixel packet codec of both protocols: building instruction packets, reading the
fields of status packets, Protocol 2.0's CRC-16 and Protocol 1.0's checksum. No IO: the bus
transactions that send and receive these bytes (deadlines, retries, the Fast Sync Read
exchange) are ``puppet.bus.link``'s. Field offsets and instruction codes are the SDK's
(``protocol1_packet_handler``, ``protocol2_packet_handler``, ``robotis_def``).
"""

from __future__ import annotations

import functools

from dynamixel_sdk import protocol1_packet_handler as p1
from dynamixel_sdk import protocol2_packet_handler as p2
from dynamixel_sdk import robotis_def as rd

PROTOCOL = 2.0
"""The protocol a link speaks unless told (every X-series servo)."""
PROTOCOLS = (1.0, 2.0)


def _crc16_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


CRC16_TABLE = _crc16_table()
"""Protocol 2.0's CRC-16 (polynomial 0x8005, the SDK's ``updateCRC`` table), built once."""


@functools.cache
def _crc16_pair_table() -> tuple[int, ...]:
    """The CRC after two bytes, indexed by (CRC before) ^ (the two bytes, big-endian): 65536
    entries, built on first use (~10 ms)."""
    t = CRC16_TABLE
    return tuple(((t[x >> 8] << 8) & 0xFFFF) ^ t[((t[x >> 8] >> 8) ^ x) & 0xFF] for x in range(65536))


def crc16(data, crc: int, start: int, end: int) -> int:
    """The Protocol 2.0 CRC-16 of ``data[start:end]`` (bytes or a list of ints), continuing
    from ``crc`` (0 to start): the SDK's ``updateCRC`` without its per-call table and slices,
    two bytes a step."""
    if (end - start) & 1:
        crc = ((crc << 8) & 0xFFFF) ^ CRC16_TABLE[((crc >> 8) ^ data[start]) & 0xFF]
        start += 1
    pairs = _crc16_pair_table()
    for i in range(start, end, 2):
        crc = pairs[crc ^ (data[i] << 8 | data[i + 1])]
    return crc


def fast_sync_read_crcs(rx, count: int, size: int) -> tuple[bool, list[int] | None]:
    """A Fast Sync Read status packet ``rx`` (bytes) for ``count`` servos of ``size`` data bytes
    -> (full, crcs). full: it holds every servo's segment ``[ERR ID data CRC]`` (broadcast id,
    the full length). crcs: computed in one CRC pass, the CRC each segment should carry (a full
    answer's), then the packet's own (its last two bytes: a full answer's are the last
    segment's); None when the packet's CRC is wrong."""
    seg = size + 4
    full = rx[4] == rd.BROADCAST_ID and len(rx) == 8 + seg * count
    sums, crc, pos = [], 0, 0
    for end in range(6 + seg, len(rx) - 2, seg) if full else ():
        crc = crc16(rx, crc, pos, end)
        sums.append(crc)
        pos = end
    if crc16(rx, crc, pos, len(rx) - 2) != rx[-2] | (rx[-1] << 8):
        return full, None
    sums.append(rx[-2] | (rx[-1] << 8))
    return full, sums


ALERT_BIT = 0x80
"""Bit 7 of a status packet's error byte: a hardware error is latched."""
STATUS_ERRORS = {
    0x01: "result fail",
    0x02: "instruction error",
    0x03: "CRC error",
    0x04: "data range error",
    0x05: "data length error",
    0x06: "data limit error",
    0x07: "access error",
}
"""Protocol 2.0 status error numbers (bits 0..6 of the error byte)."""


def describe_status_error(error: int) -> str:
    """A status packet's error byte (Protocol 2.0 form) -> text ('alert' when bit 7 is set)."""
    parts = []
    if error & ALERT_BIT:
        parts.append("alert (hardware error latched)")
    number = error & 0x7F
    if number:
        parts.append(STATUS_ERRORS.get(number, f"error number {number}"))
    return ", ".join(parts) if parts else "none"


P1_HARDWARE_BITS = 0x25
"""Protocol 1.0 status error bits that are the servo's hardware conditions: input voltage (0),
overheating (2), overload (5): the same bits as X-series Hardware Error Status (70)."""
P1_ERROR_NUMBERS = ((0x40, 0x02), (0x10, 0x03), (0x08, 0x04), (0x02, 0x06))
"""Protocol 1.0 status error bits that fail the instruction -> the Protocol 2.0 error number:
instruction (6) -> Instruction Error, checksum (4) -> CRC Error, range (3) -> Data Range Error,
angle limit (1) -> Data Limit Error."""


class Wire:
    """Where one protocol's packets keep their fields (a status packet ``rx`` as a byte list).

    Protocol 2.0: ``FF FF FD 00 ID LEN_L LEN_H 55 ERR data CRC_L CRC_H`` (CRC-16);
    Protocol 1.0: ``FF FF ID LEN ERR data CHK`` (checksum ``~(ID + LEN + ... ) & 0xFF``).
    """

    def __init__(self, protocol: float) -> None:
        if protocol not in PROTOCOLS:
            raise ValueError(f"protocol {protocol!r}: not one of {PROTOCOLS}")
        self.protocol = float(protocol)
        self.p1 = self.protocol == 1.0
        self.id_at = p1.PKT_ID if self.p1 else p2.PKT_ID
        self.error_at = p1.PKT_ERROR if self.p1 else p2.PKT_ERROR
        self.data_at = p1.PKT_PARAMETER0 if self.p1 else p2.PKT_PARAMETER0 + 1
        self.overhead = 6 if self.p1 else 11
        """Bytes of a status packet around its data."""

    def data(self, rx: list) -> list:
        """The data bytes of a status packet (all of them: the SDK would slice the asked-for
        count and take the checksum for data when a shorter reply, e.g. a late one to another
        read, comes)."""
        if self.p1:
            return rx[self.data_at: self.data_at + max(0, rx[p1.PKT_LENGTH] - 2)]
        length = rx[p2.PKT_LENGTH_L] | (rx[p2.PKT_LENGTH_H] << 8)  # instruction, error, data, CRC
        return rx[self.data_at: self.data_at + max(0, length - 4)]

    def error(self, rx: list) -> int:
        """The status error byte in the Protocol 2.0 form: bit 7 alert (Protocol 1.0: a
        hardware condition bit is set), bits 0..6 the error number."""
        raw = rx[self.error_at]
        if not self.p1:
            return raw
        number = next((n for bit, n in P1_ERROR_NUMBERS if raw & bit), 0)
        return (0x80 if raw & P1_HARDWARE_BITS else 0) | number

    def hardware_bits(self, rx: list) -> int:
        """Protocol 1.0: the hardware condition bits of a status packet (X-series Hardware
        Error Status numbering); 0 on Protocol 2.0 (read Hardware Error Status instead)."""
        return rx[self.error_at] & P1_HARDWARE_BITS if self.p1 else 0

    def stale(self, rx: list, size: int) -> bool:
        """A clean status packet whose data count is not ``size``: a late reply to another
        instruction (a reply carrying an error number may have no data: it is not stale)."""
        return not self.error(rx) & 0x7F and len(self.data(rx)) != size

    def _packet(self, body: list) -> bytes:
        """An instruction packet from its body (ID, length, instruction, parameters) with the
        header and the checksum (Protocol 1.0) or CRC-16 (Protocol 2.0) added."""
        if self.p1:
            return bytes([0xFF, 0xFF, *body, ~sum(body) & 0xFF])
        packet = [0xFF, 0xFF, 0xFD, 0x00, *body]
        crc = crc16(packet, 0, 0, len(packet))
        return bytes(packet + [crc & 0xFF, crc >> 8])

    def fast_sync_read_packet(self, ids: list[int], address: int, size: int) -> bytes:
        """Protocol 2.0 Fast Sync Read (0x8A) of ``size`` bytes at ``address`` from ``ids``:
        the bytes the SDK's ``syncReadTx`` sends (no byte stuffing: ids stop at 252 and no
        control table reaches address 0xFDFF, so ``FF FF FD`` cannot occur)."""
        n = len(ids) + 7
        return self._packet([rd.BROADCAST_ID, n & 0xFF, n >> 8, rd.INST_FAST_SYNC_READ,
                             address & 0xFF, address >> 8, size & 0xFF, size >> 8, *ids])

    def ping_packet(self, dxl_id: int) -> bytes:
        """The Ping instruction packet for one id; its status carries 3 data bytes (Protocol
        2.0: model number, firmware) or none (Protocol 1.0)."""
        if self.p1:
            return self._packet([dxl_id, 2, rd.INST_PING])
        return self._packet([dxl_id, 3, 0, rd.INST_PING])

    def ping_size(self) -> int:
        """Data bytes of a ping's status."""
        return 0 if self.p1 else 3

    def read_packet(self, dxl_id: int, address: int, size: int) -> bytes:
        """The Read instruction packet."""
        if self.p1:
            return self._packet([dxl_id, 4, rd.INST_READ, address, size])
        return self._packet([dxl_id, 7, 0, rd.INST_READ, address & 0xFF, address >> 8,
                             size & 0xFF, size >> 8])

    def status_start(self, dxl_id: int, size: int) -> bytes:
        """How a status packet from ``dxl_id`` carrying ``size`` data bytes begins."""
        if self.p1:
            return bytes((0xFF, 0xFF, dxl_id, size + 2))
        length = size + 4
        return bytes((0xFF, 0xFF, 0xFD, 0x00, dxl_id, length & 0xFF, length >> 8, 0x55))

    def read_tx(self, dxl_id: int, address: int, size: int) -> list:
        """The SDK's txRxPacket list of a Read (header and checksum filled in by the SDK)."""
        if self.p1:
            tx = [0] * 8
            tx[p1.PKT_ID], tx[p1.PKT_LENGTH], tx[p1.PKT_INSTRUCTION] = dxl_id, 4, rd.INST_READ
            tx[p1.PKT_PARAMETER0: p1.PKT_PARAMETER0 + 2] = [address, size]
            return tx
        tx = [0] * 14
        tx[p2.PKT_ID], tx[p2.PKT_LENGTH_L], tx[p2.PKT_INSTRUCTION] = dxl_id, 7, rd.INST_READ
        tx[p2.PKT_PARAMETER0: p2.PKT_PARAMETER0 + 4] = [
            address & 0xFF, address >> 8, size & 0xFF, size >> 8]
        return tx

    def write_tx(self, dxl_id: int, address: int, data: list[int]) -> list:
        """The SDK's txRxPacket list of a Protocol 1.0 Write."""
        tx = [0] * (len(data) + 7)
        tx[p1.PKT_ID], tx[p1.PKT_LENGTH], tx[p1.PKT_INSTRUCTION] = dxl_id, len(data) + 3, rd.INST_WRITE
        tx[p1.PKT_PARAMETER0] = address
        tx[p1.PKT_PARAMETER0 + 1: p1.PKT_PARAMETER0 + 1 + len(data)] = data
        return tx

    def sent(self, tx: list) -> list:
        """The whole packet of a txRxPacket list after the SDK sent it (it fills in the header
        and checksum in place)."""
        if self.p1:
            return tx[: tx[p1.PKT_LENGTH] + 4]
        return tx[: (tx[p2.PKT_LENGTH_L] | tx[p2.PKT_LENGTH_H] << 8) + 7]

    def ping_tx(self, dxl_id: int) -> list:
        """The SDK's txRxPacket list of a Ping."""
        if self.p1:
            tx = [0] * 6
            tx[p1.PKT_ID], tx[p1.PKT_LENGTH], tx[p1.PKT_INSTRUCTION] = dxl_id, 2, rd.INST_PING
            return tx
        tx = [0] * 10
        tx[p2.PKT_ID], tx[p2.PKT_LENGTH_L], tx[p2.PKT_INSTRUCTION] = dxl_id, 3, rd.INST_PING
        return tx


__all__ = ["PROTOCOL", "PROTOCOLS", "CRC16_TABLE", "crc16", "fast_sync_read_crcs", "ALERT_BIT",
           "STATUS_ERRORS", "describe_status_error", "P1_HARDWARE_BITS", "P1_ERROR_NUMBERS", "Wire"]
