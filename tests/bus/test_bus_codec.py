"""``puppet.bus.codec``: the packets of both protocols built, read and checked with no IO,
against hw_sim's device-side codec (an implementation of its own, from the e-Manual)."""

from __future__ import annotations

import random

from dynamixel_sdk import robotis_def as rd

from hw_sim import codec as sim2
from hw_sim import codec1 as sim1
from puppet.bus.codec import Wire, fast_sync_read_crcs


def test_instruction_packets_are_the_devices_bytes_on_both_protocols():
    p2, p1 = Wire(2.0), Wire(1.0)
    for dxl_id in (1, 7, 252):
        assert p2.ping_packet(dxl_id) == sim2.packet(dxl_id, rd.INST_PING)
        assert p1.ping_packet(dxl_id) == sim1.packet(dxl_id, rd.INST_PING)
        assert p2.read_packet(dxl_id, 132, 4) == sim2.packet(dxl_id, rd.INST_READ,
                                                             bytes((132, 0, 4, 0)))
        assert p1.read_packet(dxl_id, 36, 2) == sim1.packet(dxl_id, rd.INST_READ, bytes((36, 2)))
    ids = [1, 2, 3, 11, 12]
    assert p2.fast_sync_read_packet(ids, 126, 10) == sim2.packet(
        rd.BROADCAST_ID, rd.INST_FAST_SYNC_READ, bytes((126, 0, 10, 0, *ids)))


def test_status_fields_and_errors_read_from_the_devices_packets():
    p2, p1 = Wire(2.0), Wire(1.0)
    rx = list(sim2.status_packet(5, 0x80 | 0x04, bytes((0x10, 0x27, 0, 0))))
    assert (rx[p2.id_at], p2.data(rx), p2.error(rx)) == (5, [0x10, 0x27, 0, 0], 0x84)
    assert rx[: len(p2.status_start(5, 4))] == list(p2.status_start(5, 4))
    assert not p2.stale(rx, 4) and len(rx) == p2.overhead + 4
    # Protocol 1.0: overload (bit 5, a hardware condition) and a range error (bit 3) ->
    # the 2.0 form: alert + Data Range Error, the hardware bit kept apart.
    rx = list(sim1.status_packet(9, 0x20 | 0x08, bytes((0x00, 0x02))))
    assert (rx[p1.id_at], p1.data(rx), p1.error(rx), p1.hardware_bits(rx)) == (
        9, [0x00, 0x02], 0x80 | 0x04, 0x20)
    assert rx[: len(p1.status_start(9, 2))] == list(p1.status_start(9, 2))
    assert p1.stale(list(sim1.status_packet(9, 0, bytes((1,)))), 2)  # a late reply to another read


def test_fast_sync_read_segments_and_crcs_check_a_devices_reply():
    rng = random.Random(35)
    for count in (1, 3, 15):
        size = rng.choice((2, 4, 25))
        segments = [(0, i + 1, bytes(rng.randrange(256) for _ in range(size))) for i in range(count)]
        rx = bytearray(sim2.fast_status_packet(segments))
        full, crcs = fast_sync_read_crcs(rx, count, size)
        assert full and len(crcs) == count
        seg = size + 4
        assert crcs == [rx[8 + k * seg + seg - 2] | rx[8 + k * seg + seg - 1] << 8
                        for k in range(count)]  # each segment's CRC as the device sent it
        rx[10] ^= 0xFF  # the first servo's data damaged: the packet's CRC no longer holds
        assert fast_sync_read_crcs(rx, count, size)[1] is None
