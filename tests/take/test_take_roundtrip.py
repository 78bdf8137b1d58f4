"""Round trip of takes: what is written is read back exactly, by puppet and by mcap's reader."""

import struct

import numpy as np
from mcap.reader import make_reader

from puppet.take import TakeReader
from puppet.take import format as fmt


def test_roundtrip_readings_and_metadata(take_path, kit):
    r = TakeReader(take_path)
    assert len(r) == 200
    assert r.truncated is False and r.recovery is None
    assert r.valid_bytes < r.file_bytes  # the summary follows the data section
    m = r.metadata
    assert m.ids.tolist() == kit.IDS.tolist()
    assert m.models == kit.MODELS
    assert m.rig_map_text == kit.RIG_MAP
    assert m.calibration_text == kit.CALIBRATION
    assert m.rig_name == "bench"
    assert m.format_version == fmt.FORMAT_VERSION
    assert m.library.startswith("puppet/")
    for i, got in enumerate(r.readings()):
        want = kit.reading_at(i, 10_000_000 + i * 2_000_000 + (i * 37) % 100)
        assert got.t_ns == want.t_ns
        assert got.ticks.dtype == np.int32 and got.ok.dtype == np.bool_
        np.testing.assert_array_equal(got.ticks, want.ticks)
        np.testing.assert_array_equal(got.ok, want.ok)
        np.testing.assert_array_equal(got.ids, kit.IDS)
    assert r.t_first_ns == 10_000_000
    assert r.t_last_ns == 10_000_000 + 199 * 2_000_000 + (199 * 37) % 100
    assert abs(r.duration_s - (r.t_last_ns - r.t_first_ns) * 1e-9) < 1e-12


def test_arrays_match_readings(take_path, kit):
    r = TakeReader(take_path)
    t, ticks, ok = r.arrays()
    assert t.shape == (200,) and ticks.shape == (200, 4) and ok.shape == (200, 4)
    for i, got in enumerate(r.readings()):
        assert t[i] == got.t_ns
        np.testing.assert_array_equal(ticks[i], got.ticks)
        np.testing.assert_array_equal(ok[i], got.ok)


def test_readings_reordered_to_rig_order(take_path, kit):
    r = TakeReader(take_path)
    rig_ids = np.array([12, 3, 11, 7])
    perm = [3, 0, 2, 1]
    plain = list(r.readings())
    for a, b in zip(plain, r.readings(ids=rig_ids)):
        np.testing.assert_array_equal(b.ids, rig_ids)
        np.testing.assert_array_equal(b.ticks, a.ticks[perm])
        np.testing.assert_array_equal(b.ok, a.ok[perm])
    t, ticks, ok = r.arrays(ids=rig_ids)
    np.testing.assert_array_equal(ticks[:, 0], r.arrays()[1][:, 3])


def test_extreme_tick_values_survive(tmp_path, kit):
    path = tmp_path / "extreme.mcap"
    lo, hi = np.iinfo(np.int32).min, np.iinfo(np.int32).max
    with kit.open_writer(path) as w:
        r0 = kit.reading_at(0, 0)
        r0.ticks[:] = [lo, hi, 0, -1]
        w.write(r0)
    got = next(TakeReader(path).readings())
    assert got.ticks.tolist() == [lo, hi, 0, -1]
    assert got.t_ns == 0


def test_empty_take_closed_cleanly(tmp_path, kit):
    path = tmp_path / "empty.mcap"
    kit.open_writer(path).close()
    r = TakeReader(path)
    assert len(r) == 0 and r.duration_s == 0.0 and r.truncated is False
    assert list(r.readings()) == []
    assert r.arrays()[1].shape == (0, 4)


def test_standard_mcap_reader_decodes_the_take(take_path, kit):
    """mcap's own reader sees a valid MCAP; the CDR payload decodes by the documented layout."""
    with open(take_path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 200
        metas = {m.name: m.metadata for m in reader.iter_metadata()}
        assert metas[fmt.RIG_MAP_METADATA]["text"] == kit.RIG_MAP
        n = 0
        for schema, channel, message in reader.iter_messages(topics=[fmt.TOPIC]):
            assert schema.name == "puppet_msgs/msg/ServoReading" and schema.encoding == "ros2msg"
            assert channel.message_encoding == "cdr"
            assert channel.metadata["ids"] == "3,7,11,12"
            d = message.data
            assert d[:4] == b"\x00\x01\x00\x00"
            t_ns, k1 = struct.unpack_from("<qI", d, 4)
            ticks = struct.unpack_from("<4i", d, 16)
            (k2,) = struct.unpack_from("<I", d, 32)
            ok = struct.unpack_from("<4B", d, 36)
            want = kit.reading_at(n, message.log_time)
            assert (k1, k2) == (4, 4) and t_ns == message.log_time == message.publish_time
            assert list(ticks) == want.ticks.tolist()
            assert [bool(b) for b in ok] == want.ok.tolist()
            assert message.sequence == n
            n += 1
        assert n == 200


def test_take_rewritten_chunked_by_an_mcap_tool(take_path, tmp_path, kit):
    """MCAP tools may rewrite a take chunked and compressed; it reads back the same."""
    from mcap.writer import CompressionType, Writer

    out = tmp_path / "chunked.mcap"
    with open(take_path, "rb") as f, open(out, "wb") as g:
        reader = make_reader(f)
        w = Writer(g, chunk_size=1000, compression=CompressionType.ZSTD)
        w.start(profile="", library=reader.get_header().library)
        for m in reader.iter_metadata():
            w.add_metadata(m.name, m.metadata)
        schema_ids, channel_ids = {}, {}
        for schema, channel, message in reader.iter_messages():
            if schema.id not in schema_ids:
                schema_ids[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channel_ids:
                channel_ids[channel.id] = w.register_channel(
                    channel.topic, channel.message_encoding, schema_ids[schema.id], channel.metadata
                )
            w.add_message(channel_ids[channel.id], message.log_time, message.data,
                          message.publish_time, message.sequence)
        w.finish()
    a, b = TakeReader(take_path), TakeReader(out)
    assert len(b) == len(a) == 200 and b.truncated is False
    assert b.metadata.rig_map_text == kit.RIG_MAP
    for x, y in zip(a.arrays(), b.arrays()):
        np.testing.assert_array_equal(x, y)
    assert [r.t_ns for r in b.readings()] == [r.t_ns for r in a.readings()]
    assert b.t_last_ns == a.t_last_ns
