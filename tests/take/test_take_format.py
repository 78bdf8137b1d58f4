"""Take formats 2 and 3: checksummed readings and metadata; version-1 takes still read; damage is
skipped and reported, never replayed, and never loses the intact readings around it."""

import json
import struct
import zlib

import numpy as np
from mcap.writer import CompressionType, Writer

from puppet.reading import Reading
from puppet.take import TakeReader, TakeWriter
from puppet.take import format as fmt

RECORD_HEAD = 9 + 22  # MCAP record head (opcode, length) + message head before the payload


def message_starts(data: bytes) -> list[int]:
    """Byte offsets of every message record of an unchunked MCAP file."""
    pos, out = 8, []
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x0F:
            break
        if opcode == 0x05:
            out.append(pos)
        pos += 9 + length
    return out


def write_take(path, kit, n):
    with kit.open_writer(path) as w:
        for i in range(n):
            w.write(kit.reading_at(i, 1_000 + i * 2_000_000))
    return path.read_bytes()


def assert_readings(r, kit, indices, t=lambda i: 1_000 + i * 2_000_000):
    got = list(r.readings())
    assert [g.t_ns for g in got] == [t(i) for i in indices]
    assert [g.ticks.tolist() for g in got] == [kit.reading_at(i, 0).ticks.tolist() for i in indices]
    assert [g.ok.tolist() for g in got] == [kit.reading_at(i, 0).ok.tolist() for i in indices]
    tt, ticks, ok = r.arrays()
    assert tt.tolist() == [g.t_ns for g in got]
    assert ticks.tolist() == [g.ticks.tolist() for g in got]


def test_payload_layout_and_checksum(kit):
    for k in (1, 2, 3, 4, 5, 15):
        codec = fmt.ReadingCodec(k)
        assert codec.size == fmt.message_size(k) == 24 + 5 * k + (-k) % 4
        assert fmt.message_size(k, 1) == 20 + 5 * k
        payload = bytes(codec.encode(123, np.arange(k), np.ones(k, bool)))
        crc_at = fmt.crc_offset(k)
        assert crc_at % 4 == 0  # CDR aligns the uint32 (the origin, offset 4, is aligned too)
        assert payload[20 + 5 * k : crc_at] == bytes(crc_at - 20 - 5 * k)
        assert int.from_bytes(payload[crc_at:], "little") == zlib.crc32(payload[:crc_at])
        assert codec.check(payload) is None
        for off in range(len(payload)):  # every single flipped byte is detected
            bad = bytearray(payload)
            bad[off] ^= 0x5A
            assert codec.check(bytes(bad)) is not None, (k, off)
    assert fmt.SCHEMA_TEXT_V2.startswith(fmt.SCHEMA_TEXT_V1) and "uint32 crc" in fmt.SCHEMA_TEXT
    assert "uint8[] ok" in fmt.SCHEMA_TEXT  # version 3: 0 a fault, 1 read, 2 late


def test_metadata_checksums(tmp_path, kit):
    p = tmp_path / "t.mcap"
    write_take(p, kit, 3)
    r = TakeReader(p)
    assert r.recovery is None and r.report.clean
    assert r.metadata.format_version == fmt.FORMAT_VERSION == 3
    info = {"a": "1", "b": "x"}
    assert fmt.info_checksum(info) == fmt.info_checksum({**info, "crc32": "whatever"})
    assert fmt.info_checksum(info) != fmt.info_checksum({"a": "2", "b": "x"})


def write_v1_take(path, kit, times, log_times=None):
    """A version-1 take as puppet 0.1 wrote it (no checksums), with the given timestamps."""
    codec = fmt.ReadingCodec(len(kit.IDS), version=1)
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.NONE, use_chunking=False)
        w.start(profile="", library="puppet/0.1.0")
        w.add_metadata(fmt.TAKE_METADATA, {
            "format_version": "1", "rig_name": "bench", "ids": json.dumps(kit.IDS.tolist()),
            "models": json.dumps({str(i): m for i, m in kit.MODELS.items()}),
            "servo_count": str(len(kit.IDS)), "created_unix_ns": "5"})
        w.add_metadata(fmt.RIG_MAP_METADATA, {"text": kit.RIG_MAP})
        w.add_metadata(fmt.CALIBRATION_METADATA, {"text": kit.CALIBRATION})
        sid = w.register_schema(fmt.SCHEMA_NAME, fmt.SCHEMA_ENCODING, fmt.SCHEMA_TEXT_V1.encode())
        ch = w.register_channel(fmt.TOPIC, fmt.MESSAGE_ENCODING, sid, {"ids": "3,7,11,12"})
        for i, t in enumerate(times):
            r = kit.reading_at(i, t)
            log = t if log_times is None else log_times[i]
            w.add_message(ch, log_time=log, data=bytes(codec.encode(t, r.ticks, r.ok)),
                          publish_time=log, sequence=i)
        w.finish()


def test_version_1_takes_still_read(tmp_path, kit):
    p = tmp_path / "v1.mcap"
    write_v1_take(p, kit, [1_000 + i * 2_000_000 for i in range(20)])
    r = TakeReader(p)
    assert r.recovery is None and r.truncated is False
    assert r.metadata.format_version == 1
    assert r.metadata.rig_map_text == kit.RIG_MAP and r.metadata.calibration_text == kit.CALIBRATION
    assert_readings(r, kit, range(20))


def test_version_1_timestamps_are_checked(tmp_path, kit):
    """Without a checksum, a reading whose time disagrees with its log time or goes backwards
    is skipped and reported; the readings after it are kept."""
    times = [1_000 + i * 2_000_000 for i in range(20)]
    logs = list(times)
    times[5] += 1 << 50  # a flipped high byte of the reading's own time: 36 years later
    logs[9] = 3  # a flipped log time
    times[12] = logs[12] = times[11] - 1  # goes backwards
    times[15] = logs[15] = times[14] - 5  # backwards again
    p = tmp_path / "v1.mcap"
    write_v1_take(p, kit, times, logs)
    r = TakeReader(p)
    kept = [i for i in range(20) if i not in (5, 9, 12, 15)]
    assert_readings(r, kit, kept)
    assert r.report.skipped == {"log time disagrees": 2, "out of order": 2}
    assert "log time 3 ns" in r.recovery and r.truncated is False


def test_every_flipped_byte_of_a_reading_is_skipped_alone(tmp_path, kit):
    p = tmp_path / "t.mcap"
    data = write_take(p, kit, 8)
    starts = message_starts(data)
    size = starts[1] - starts[0]
    assert all(b - a == size for a, b in zip(starts, starts[1:]))  # one size for every reading
    damaged = tmp_path / "d.mcap"
    for off in range(size):
        bad = bytearray(data)
        bad[starts[3] + off] ^= 0xA5
        damaged.write_bytes(bytes(bad))
        r = TakeReader(damaged)
        # A flip in the message's sequence number or publish time leaves the reading intact.
        harmless = 9 + 2 <= off < 9 + 6 or 9 + 14 <= off < 9 + 22
        assert_readings(r, kit, range(8) if harmless else [0, 1, 2, 4, 5, 6, 7])
        assert (r.report.skipped_count == 0) == harmless, off
        assert (r.recovery is None) == harmless, off


def test_garbage_inside_the_readings_is_stepped_over(tmp_path, kit):
    p = tmp_path / "t.mcap"
    data = write_take(p, kit, 10)
    starts = message_starts(data)
    # 37 bytes of garbage inserted between readings 4 and 5, and reading 7 overwritten by zeros
    bad = bytearray(data[: starts[5]] + bytes(range(200, 237)) + data[starts[5]:])
    s7 = starts[7] + 37
    bad[s7 : s7 + starts[1] - starts[0]] = bytes(starts[1] - starts[0])
    p.write_bytes(bytes(bad))
    r = TakeReader(p)
    assert_readings(r, kit, [0, 1, 2, 3, 4, 5, 6, 8, 9])
    assert r.report.skipped == {"corrupt record": 2}
    assert f"resumed at byte {starts[5] + 37}" in r.recovery
    assert r.truncated is False


def test_damaged_rig_map_and_calibration_lose_no_reading(tmp_path, kit):
    p = tmp_path / "t.mcap"
    data = write_take(p, kit, 6)
    for text, field, name in ((kit.RIG_MAP, "rig map", fmt.RIG_MAP_METADATA),
                              (kit.CALIBRATION, "calibration", fmt.CALIBRATION_METADATA)):
        at = data.find(text.encode())
        bad = bytearray(data)
        bad[at + 5] ^= 0x01  # one character of the text
        p.write_bytes(bytes(bad))
        r = TakeReader(p)
        assert_readings(r, kit, range(6))
        assert f"the {field} metadata is damaged (checksum mismatch)" in r.recovery
        m = r.metadata
        assert (m.rig_map_text, m.calibration_text) == (
            ("", kit.CALIBRATION) if field == "rig map" else (kit.RIG_MAP, ""))
        # The record's name length: the record no longer parses; it is stepped over.
        bad = bytearray(data)
        bad[data.find(name.encode()) - 1] ^= 0x40
        p.write_bytes(bytes(bad))
        r = TakeReader(p)
        assert_readings(r, kit, range(6))
        assert f"no {field} metadata (its record is damaged or missing)" in r.recovery


def test_damaged_take_metadata_falls_back_to_the_channel_record(tmp_path, kit):
    p = tmp_path / "t.mcap"
    data = write_take(p, kit, 6)
    at = data.find(b"XM430-W350")
    bad = bytearray(data)
    bad[at] ^= 0x02  # a model name: the take metadata's checksum no longer matches
    p.write_bytes(bytes(bad))
    r = TakeReader(p)
    assert_readings(r, kit, range(6))
    assert "take metadata record is damaged (checksum mismatch)" in r.recovery
    assert r.metadata.ids.tolist() == kit.IDS.tolist() and r.metadata.models == {}
    assert r.metadata.format_version == fmt.FORMAT_VERSION  # from the schema


def test_damaged_magic_bytes(tmp_path, kit):
    p = tmp_path / "t.mcap"
    data = bytearray(write_take(p, kit, 4))
    data[3] ^= 0xFF
    p.write_bytes(bytes(data))
    r = TakeReader(p)
    assert_readings(r, kit, range(4))
    assert "magic bytes are damaged" in r.recovery


def test_marks_on_their_own_channel_are_not_damage(tmp_path):
    """A take with named marks (the live view's marker button) reads clean, marks in order."""
    from puppet.take.markers import read_markers

    path = tmp_path / "marked.mcap"
    with TakeWriter(path, ids=[1, 2], models={1: "XL330-M288", 2: "XL330-M288"},
                    rig_map_text="", calibration_text="", rig_name="x") as writer:
        for i in range(6):
            writer.write(Reading(1_000 + i * 1_000_000, np.array([1, 2]),
                                 np.array([i, 2 * i], np.int32), np.ones(2, bool)))
            if i in (2, 3):
                writer.mark(1_000 + i * 1_000_000, f"mark {i}")
                writer.mark(1_000 + i * 1_000_000, f"again {i}")
    reader = TakeReader(path)
    assert len(reader) == 6
    assert reader.recovery is None
    assert [name for _, name in read_markers(path)] == ["mark 2", "again 2", "mark 3", "again 3"]
