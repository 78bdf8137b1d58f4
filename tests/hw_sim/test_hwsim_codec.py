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


# ---- Protocol 1.0 (hw_sim.codec1) --------------------------------------------------------------
def test_p1_packets_match_emanual():
    from hw_sim import codec1

    # e-manual Protocol 1.0 example: write 100 and 170 at address 12 of servo 1.
    assert codec1.packet(1, codec1.WRITE, bytes((0x0C, 0x64, 0xAA))) == \
        bytes.fromhex("ff ff 01 05 03 0c 64 aa dc")
    assert codec1.status_packet(1, 0) == bytes.fromhex("ff ff 01 02 00 fc")
    assert codec1.status_packet(1, 0x20, b"\x00\x02") == bytes.fromhex("ff ff 01 04 20 00 02 d8")


def test_p1_parser_skips_garbage_splits_and_flags_bad_checksums():
    from hw_sim import codec1

    read = codec1.packet(3, codec1.READ, bytes((36, 2)))
    parser = codec1.InstructionParser()
    assert parser.feed(b"\x00\x12\xff" + read[:5]) == []  # garbage, a lone FF, half a packet
    (ins,) = parser.feed(read[5:])
    assert (ins.dxl_id, ins.inst, ins.params, ins.raw_len, ins.crc_ok) == (3, 0x02, b"\x24\x02", 8, True)
    (shifted,) = parser.feed(b"\xff" + read)  # FF FF FF: the header starts one byte later
    assert (shifted.dxl_id, shifted.crc_ok) == (3, True)
    (bad,) = parser.feed(read[:-1] + bytes((read[-1] ^ 0xFF,)))
    assert (bad.dxl_id, bad.crc_ok) == (3, False)
    assert parser.pending == 0


def test_p1_error_byte_maps_errors_and_keeps_hardware_bits():
    from hw_sim import codec, codec1

    assert codec1.error_byte(codec.ERR_DATA_LIMIT, 0) == codec1.ERR_ANGLE
    assert codec1.error_byte(codec.ERR_ACCESS, 0) == codec1.ERR_RANGE
    assert codec1.error_byte(codec.ERR_CRC, 0) == codec1.ERR_CHECKSUM
    assert codec1.error_byte(codec.ERR_INSTRUCTION, 0) == codec1.ERR_INSTRUCTION
    # overheating and overload sit at the same bits; encoder / electrical shock have none.
    assert codec1.error_byte(0, 0x04 | 0x20 | 0x08 | 0x10) == codec1.ERR_OVERHEAT | codec1.ERR_OVERLOAD
    assert codec.error_byte(codec.ERR_ACCESS, 0x20) == codec.ERR_ACCESS | codec.ALERT
