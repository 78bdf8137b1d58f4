"""A take's channels are known by their schema (and the readings by their checksums) when a
damaged byte changes a topic name: one flipped byte loses no reading, key or mark."""

import numpy as np
import pytest

from puppet.take import TakeReader, format as fmt
from puppet.take.keys import KEY_SCHEMA_NAME, KEY_TOPIC, Key, Keys
from puppet.take.markers import MARKER_TOPIC, read_markers


def _shot(path, kit):
    """Ten readings, two marks and three keys (a shot's keys at frames 1, 5, 10)."""
    with kit.open_writer(path) as writer:
        for i in range(10):
            writer.write(kit.reading_at(i, i * 100_000_000))
            if i in (2, 7):
                writer.mark(i * 100_000_000, f"mark {i}")
        keys = [Key(frame, kit.reading_at(frame, 0).ticks, np.ones(4, bool), "linear")
                for frame in (1, 5, 10)]
        writer.keys(Keys(10.0, keys))
    return path


def _flip(path, text: str, at: int = 3, count=None) -> None:
    """Flip one byte of every (or the first ``count``) occurrence(s) of ``text`` in the file."""
    data = bytearray(path.read_bytes())
    needle, start, done = text.encode(), 0, 0
    while (q := data.find(needle, start)) != -1 and (count is None or done < count):
        data[q + at] ^= 0x20
        start, done = q + 1, done + 1
    assert done, text
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("topic", [fmt.TOPIC, KEY_TOPIC, MARKER_TOPIC])
def test_a_flipped_byte_in_a_topic_name_loses_nothing(topic, tmp_path, kit):
    whole = TakeReader(_shot(tmp_path / "whole.mcap", kit))
    path = _shot(tmp_path / "flipped.mcap", kit)
    _flip(path, topic)
    damaged = TakeReader(path)
    assert len(damaged) == len(whole) == 10
    t, ticks, ok = damaged.arrays()
    assert (ticks == whole.arrays()[1]).all() and (t == whole.arrays()[0]).all()
    assert [k.frame for k in damaged.keys().keys] == [1, 5, 10]
    assert read_markers(path) == read_markers(whole.path) == [(200_000_000, "mark 2"),
                                                              (700_000_000, "mark 7")]
    assert "by its schema (its topic name is damaged)" in damaged.recovery


def test_readings_whose_topic_and_schema_names_are_damaged_are_known_by_checksum(tmp_path, kit):
    path = _shot(tmp_path / "both.mcap", kit)
    _flip(path, fmt.TOPIC)
    _flip(path, fmt.SCHEMA_NAME)
    _flip(path, "uint32 crc")  # the schema text too: neither name nor schema says readings
    reader = TakeReader(path)
    assert len(reader) == 10
    assert "readings recognised by checksum" in reader.recovery


def test_a_keys_channel_whose_topic_and_schema_name_are_damaged_is_known_by_its_schema_text(
        tmp_path, kit):
    path = _shot(tmp_path / "keys.mcap", kit)
    _flip(path, KEY_TOPIC)
    _flip(path, KEY_SCHEMA_NAME)
    assert [k.frame for k in TakeReader(path).keys().keys] == [1, 5, 10]
