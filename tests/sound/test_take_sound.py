"""The take's reference to its sound and its start timecode (puppet.take.sync): written by
TakeWriter, read by TakeReader, found again beside the take (puppet.sound.locate)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import soundfile as sf

from puppet.reading import Reading
from puppet.sound import SoundError, find_take_sound, keep_copy, load_sound, sound_ref
from puppet.take import TakeReader, TakeWriter
from puppet.take import sync
from puppet.timecode import StartTimecode

IDS = np.array([1, 2], np.int64)


def write_take(path, **kw):
    with TakeWriter(path, ids=IDS, models={1: "XL430-W250", 2: "XL430-W250"}, rig_map_text="",
                    calibration_text="", rig_name="t", **kw) as w:
        for i in range(5):
            w.write(Reading(t_ns=i * 10_000_000, ids=IDS, ticks=np.array([i, -i], np.int32),
                            ok=np.ones(2, bool)))
    return path


@pytest.fixture
def voice(tmp_path, clicks):
    folder = tmp_path / "audio"
    folder.mkdir()
    path = folder / "voice é.flac"
    sf.write(path, clicks.click_track(48000), 48000)
    return load_sound(path)


def test_sound_and_timecode_round_trip(tmp_path, voice):
    ref = sound_ref(voice, offset_s=1.25)
    start = StartTimecode("01:02:03;04", "29.97")
    take = write_take(tmp_path / "take.mcap", sound=ref, timecode=start)
    reader = TakeReader(take)
    assert reader.recovery is None
    assert reader.metadata.sound == ref
    assert reader.metadata.sound.offset_s == 1.25 and reader.metadata.sound.rate == 48000
    assert reader.metadata.timecode == start
    assert len(reader) == 5


def test_a_take_without_them_has_none(tmp_path):
    reader = TakeReader(write_take(tmp_path / "take.mcap"))
    assert reader.metadata.sound is None and reader.metadata.timecode is None
    assert reader.recovery is None


def test_a_damaged_sound_record_is_left_out_and_said(tmp_path, voice):
    take = write_take(tmp_path / "take.mcap", sound=sound_ref(voice, 0.5))
    data = bytearray(take.read_bytes())
    at = data.index(b"offset_s") + len("offset_s") + 4 + 1  # inside the offset's value text
    data[at] = ord("7") if data[at] != ord("7") else ord("8")
    take.write_bytes(bytes(data))
    reader = TakeReader(take)
    assert reader.metadata.sound is None
    assert "the sound metadata is damaged (checksum mismatch)" in reader.recovery
    assert len(reader) == 5


def test_find_by_stored_path_then_beside_the_take(tmp_path, voice):
    ref = sound_ref(voice, 0.0)
    (tmp_path / "session").mkdir()
    take = write_take(tmp_path / "session" / "take.mcap", sound=ref)
    found, warning = find_take_sound(ref, take)
    assert warning is None and found.path == voice.path
    # the sound moved: found beside the take (its sounds/ folder), checked by its hash
    copy = keep_copy(voice, take.parent)
    assert copy == take.parent / "sounds" / voice.name
    assert keep_copy(voice, take.parent) == copy  # same content: the same copy
    moved = tmp_path / "elsewhere.flac"
    shutil.move(voice.path, moved)
    found, warning = find_take_sound(ref, take)
    assert warning is None and found.path == copy and found.sha256 == ref.sha256


def test_a_missing_or_changed_sound_plays_silent_with_one_warning(tmp_path, voice, clicks):
    ref = sound_ref(voice, 0.0)
    (tmp_path / "s").mkdir()
    take = write_take(tmp_path / "s" / "take.mcap", sound=ref)
    sf.write(voice.path, clicks.click_track(48000, seconds=1.0), 48000)  # other content, same name
    found, warning = find_take_sound(ref, take)
    assert found is None
    assert warning.startswith(f"{take}: its sound {voice.name} (sha256 {ref.sha256[:12]}")
    assert warning.endswith("playing silent")
    assert "has other content" in warning


def test_keep_copy_never_writes_over_another_file(tmp_path, voice, clicks):
    sounds = tmp_path / "session" / "sounds"
    sounds.mkdir(parents=True)
    other = sounds / voice.name
    sf.write(other, clicks.click_track(48000, seconds=0.5), 48000)
    before = other.read_bytes()
    copy = keep_copy(voice, tmp_path / "session")
    assert copy.name == f"{voice.path.stem}-{voice.sha256[:8]}.flac"
    assert other.read_bytes() == before
    assert load_sound(copy).sha256 == voice.sha256


def test_sound_ref_refuses_an_offset_out_of_range(voice):
    with pytest.raises(SoundError, match="offset_s must be"):
        sound_ref(voice, offset_s=1e9)
    with pytest.raises(ValueError, match="checksum"):
        sync.SoundRef.from_metadata({**sound_ref(voice).to_metadata(), "rate": "44100"})
