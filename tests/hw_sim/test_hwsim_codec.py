"""Device-side codec: the e-manual's example packets byte for byte, stuffing, header search."""

from hw_sim import codec
from hw_sim.codec import InstructionParser

PING_1 = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
FAST_SYNC_READ_REPLY = bytes.fromhex(
    "FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA"
    " 00 04 FF 03 00 00 D1 9E")


def test_ping_packet_matches_emanual():
    assert codec.packet(1, codec.PING) == PING_1
    assert codec.crc16(PING_1[:-2]) == 0x4E19


def test_read_status_example_crc():
    assert codec.status_packet(1, 0, bytes([0xA6, 0, 0, 0])) == bytes.fromhex(
        "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")


def test_sync_read_instruction_example():
    pkt = codec.packet(0xFE, codec.SYNC_READ, bytes([0x84, 0, 4, 0, 1, 2]))
    assert pkt == bytes.fromhex("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA")


def test_fast_sync_read_reply_matches_emanual():
    segments = [(0, 3, bytes([0xA6, 0, 0, 0])), (0, 7, bytes([0x1F, 8, 0, 0])),
                (0, 4, bytes([0xFF, 3, 0, 0]))]
    assert codec.fast_status_packet(segments) == FAST_SYNC_READ_REPLY
    # Each segment CRC is the running CRC of every byte before it.
    assert codec.crc16(FAST_SYNC_READ_REPLY[:14]) == 0x0884
    assert codec.crc16(FAST_SYNC_READ_REPLY[:22]) == 0xCA16


def test_stuffing_round_trip_and_length():
    data = bytes([0xFF, 0xFF, 0xFD, 0x00])
    pkt = codec.status_packet(1, 0, data)
    assert b"\xff\xff\xfd\xfd" in pkt[7:]
    assert pkt[5] | pkt[6] << 8 == len(pkt) - 7
    assert codec.unstuff(codec.stuff(data)) == data


def test_parser_skips_garbage_and_stuffed_headers():
    parser = InstructionParser()
    write = codec.packet(1, codec.WRITE, bytes([116, 0, 0xFF, 0xFF, 0xFD, 0x00]))
    got = parser.feed(b"\x00\xff\x13" + write + PING_1[:4])
    assert [(i.dxl_id, i.inst, i.params) for i in got] == [
        (1, codec.WRITE, bytes([116, 0, 0xFF, 0xFF, 0xFD, 0x00]))]
    got = parser.feed(PING_1[4:])
    assert [(i.dxl_id, i.inst, i.crc_ok) for i in got] == [(1, codec.PING, True)]


def test_parser_flags_bad_crc():
    bad = PING_1[:-1] + b"\x00"
    (ins,) = InstructionParser().feed(bad)
    assert ins.crc_ok is False
