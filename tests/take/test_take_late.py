"""Take format 3 keeps why a servo's value was held: a late reply (a busy host, not a fault)
reads back late, and a replay paints it as the live run did (``Reading.late``, ``fault_mask``),
never as a fault; a real fault stays a fault; takes of format 1 and 2 (no reason kept) read with
late None, every servo not ok at fault, as before."""

import numpy as np

from puppet.reading import Reading, fault_mask
from puppet.take import Playback, TakeReader
from puppet.take import format as fmt

IDS = np.array([3, 7, 11, 12], dtype=np.int64)


def _reading(i: int) -> Reading:
    """Reading i: servo 7 late in readings 2 and 3, servo 11 faulted in reading 3, the rest ok."""
    ok = np.ones(4, bool)
    late = np.zeros(4, bool)
    if i in (2, 3):
        ok[1], late[1] = False, True
    if i == 3:
        ok[2] = False
    ticks = np.array([10 * i, 20 * i, 30 * i, 40 * i], np.int32)
    return Reading(t_ns=1_000_000_000 + i * 10_000_000, ids=IDS, ticks=ticks, ok=ok, late=late)


def _write(path, kit, n=6):
    with kit.open_writer(path) as w:
        for i in range(n):
            w.write(_reading(i))
    return path


def test_a_late_reply_reads_back_late_and_a_fault_a_fault(tmp_path, kit):
    r = TakeReader(_write(tmp_path / "t.mcap", kit))
    assert r.metadata.format_version == 3 and r.report.clean
    got = list(r.readings())
    for i, reading in enumerate(got):
        want = _reading(i)
        assert reading.ok.tolist() == want.ok.tolist(), i
        assert reading.late.tolist() == want.late.tolist(), i
    assert fault_mask(got[2], np.empty(4, bool)).tolist() == [False] * 4  # late: no fault
    assert fault_mask(got[3], np.empty(4, bool)).tolist() == [False, False, True, False]
    _, _, ok = r.arrays()
    late = r.late()
    assert late.shape == ok.shape == (6, 4)
    assert late[:, 1].tolist() == [False, False, True, True, False, False]
    assert not (late & ok).any()
    order = [12, 11, 7, 3]  # the rig's order
    assert r.late(order)[:, 2].tolist() == late[:, 1].tolist()
    assert list(r.readings(order))[2].late.tolist() == [False, False, True, False]


def test_a_replay_keeps_late_replies_late_between_readings_and_in_a_clip(tmp_path, kit):
    r = TakeReader(_write(tmp_path / "t.mcap", kit))
    play = Playback.of_take(r, IDS, fps=200.0)  # two frames per reading (10 ms apart)
    frames = list(play)
    by_time = {f.t_ns: f for f in frames}
    at_2 = by_time[1_020_000_000]
    assert at_2.ok.tolist() == [True, False, True, True] and at_2.late.tolist() == [False, True, False, False]
    between_1_2 = by_time[1_015_000_000]  # ok on one side, late on the other: late
    assert between_1_2.late.tolist() == [False, True, False, False]
    assert fault_mask(between_1_2, np.empty(4, bool)).tolist() == [False] * 4
    between_2_3 = by_time[1_025_000_000]  # servo 11 faulted in reading 3: a fault, 7 late
    assert between_2_3.ok.tolist() == [True, False, False, True]
    assert fault_mask(between_2_3, np.empty(4, bool)).tolist() == [False, False, True, False]
    clip = play.clip(0.012, 0.045)  # in and out points between readings
    assert any(f.late is not None and f.late[1] for f in clip)
    assert all(not f.late[2] for f in clip)  # the fault stays a fault


def test_older_takes_have_no_late_mask_every_servo_not_ok_is_at_fault(tmp_path, kit):
    path = tmp_path / "v2.mcap"
    with kit.open_writer(path) as w:
        w._codec = fmt.ReadingCodec(len(IDS), version=2)  # what puppet wrote before format 3
        for i in range(6):
            w.write(_reading(i))
    data = path.read_bytes()
    # the same file as a version 2 take: its metadata and schema say 2
    v2 = _as_version_2(data)
    path.write_bytes(v2)
    r = TakeReader(path)
    assert r.metadata.format_version == 2, r.recovery
    got = list(r.readings())
    assert got[2].late is None and r.late() is None
    assert fault_mask(got[2], np.empty(4, bool)).tolist() == [False, True, False, False]
    assert all(f.late is None for f in Playback.of_take(r, IDS, fps=100.0))


def _as_version_2(data: bytes) -> bytes:
    """A take written with the version-2 codec, relabelled version 2 (a take of puppet before
    format 3): its schema text and metadata version, checksums redone."""
    import io

    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    reader = make_reader(io.BytesIO(data))
    out = io.BytesIO()
    w = Writer(out, compression=CompressionType.NONE, use_chunking=False)
    w.start(profile="", library="puppet/0.2.0")
    for record in reader.iter_metadata():
        meta = dict(record.metadata)
        if record.name == fmt.TAKE_METADATA:
            meta["format_version"] = "2"
            meta["crc32"] = fmt.info_checksum(meta)
        w.add_metadata(record.name, meta)
    channels = {}
    for schema, channel, message in reader.iter_messages():
        if channel.id not in channels:
            text = fmt.SCHEMA_TEXT_V2.encode() if channel.topic == fmt.TOPIC else schema.data
            sid = w.register_schema(schema.name, schema.encoding, text)
            channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                      sid, dict(channel.metadata))
        w.add_message(channels[channel.id], log_time=message.log_time, data=message.data,
                      publish_time=message.publish_time, sequence=message.sequence)
    w.finish()
    return out.getvalue()


def test_an_ok_byte_no_version_3_writes_is_a_malformed_reading():
    """A payload whose checksum holds but whose ok byte is none of 0, 1, 2 (a writer's bug, a
    foreign tool): refused as malformed, never read as a fault or a late reply."""
    import zlib

    codec = fmt.ReadingCodec(4)
    payload = bytearray(codec.encode(5, np.arange(4, dtype=np.int32), np.ones(4, bool),
                                     np.zeros(4, bool)))
    assert codec.check(bytes(payload)) is None
    payload[20 + 4 * 4 + 1] = 7
    payload[codec.crc_at:] = zlib.crc32(payload[:codec.crc_at]).to_bytes(4, "little")
    assert codec.check(bytes(payload)) == ("malformed reading", "ok byte 7, expected 0, 1 or 2")
