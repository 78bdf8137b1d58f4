"""Decoding sounds (puppet.sound.decode): WAV, FLAC, OGG, MP3 by libsndfile, bad input refused
naming the file."""

from __future__ import annotations

import os

import numpy as np
import pytest
import soundfile as sf

from puppet import limits
from puppet.sound import Sound, SoundError, file_sha256, load_sound


@pytest.mark.parametrize("suffix, lossy", [(".wav", False), (".flac", False), (".ogg", True),
                                           (".mp3", True)])
def test_every_format_decodes_to_its_clicks(tmp_path, suffix, lossy, clicks):
    track = clicks.click_track(44100, channels=2)
    path = tmp_path / f"voice{suffix}"
    sf.write(path, track, 44100)
    before = path.read_bytes()
    sound = load_sound(path)
    assert isinstance(sound, Sound)
    assert sound.rate == 44100 and sound.channels == 2
    assert sound.samples.dtype == np.float32 and not sound.samples.flags.writeable
    assert sound.sha256 == file_sha256(path) and len(sound.sha256) == 64
    assert sound.path == path.absolute() and sound.name == f"voice{suffix}"
    if lossy:  # codecs pad and delay: the clicks are where they were within a millisecond
        assert abs(sound.duration_s - 2.5) < 0.1
        got = clicks.onsets(sound.samples[:, 0], sound.rate)
        assert len(got) == len(clicks.CLICK_TIMES_S)
        assert np.max(np.abs(np.array(got) - clicks.CLICK_TIMES_S)) < 1e-3
        lag = clicks.lag_samples(sound.samples[:len(track), 0], track[:, 0])
        assert abs(lag) <= 44  # 1 ms
    else:
        assert sound.frames == len(track)
        np.testing.assert_allclose(sound.samples, track, atol=1e-4)
    assert path.read_bytes() == before  # an input: never written


def test_undecodable_file_is_refused_by_name(tmp_path):
    path = tmp_path / "notes.wav"
    path.write_text("these are not samples\n" * 20)
    with pytest.raises(SoundError, match=r"notes\.wav: cannot decode it as a sound: not a WAV"):
        load_sound(path)
    mp3 = tmp_path / "noise.mp3"
    mp3.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(SoundError, match=r"noise\.mp3: cannot decode it as a sound") as caught:
        load_sound(mp3)
    assert "does not exist" not in str(caught.value)


def test_empty_and_missing_files_are_refused(tmp_path):
    empty = tmp_path / "empty.wav"
    empty.write_bytes(b"")
    with pytest.raises(SoundError, match=r"empty\.wav: empty file"):
        load_sound(empty)
    silent = tmp_path / "nothing.wav"
    sf.write(silent, np.zeros((0, 1), np.float32), 48000)
    with pytest.raises(SoundError, match=r"nothing\.wav: holds no samples"):
        load_sound(silent)
    with pytest.raises(SoundError, match=r"gone\.wav: no such sound file"):
        load_sound(tmp_path / "gone.wav")
    with pytest.raises(SoundError, match="not a regular file"):
        load_sound(tmp_path)


def test_odd_rate_is_refused(tmp_path):
    path = tmp_path / "odd.wav"
    sf.write(path, np.zeros((1000, 1), np.float32), 12345)
    with pytest.raises(SoundError, match=r"odd\.wav: sample rate 12345 Hz is not a standard rate"):
        load_sound(path)


def test_too_long_is_refused_before_decoding(tmp_path):
    """The header says how long: a sound over SOUND_SECONDS_MAX is refused without decoding it
    (a sparse WAV file whose header claims the length)."""
    path = tmp_path / "long.wav"
    rate = 8000
    frames = int(limits.SOUND_SECONDS_MAX * rate) + rate * 60
    with sf.SoundFile(path, "w", rate, 1, subtype="PCM_U8") as f:
        f.write(np.zeros((rate, 1), np.float32))
    # grow the data chunk to `frames` bytes (PCM_U8: one byte a frame) and patch the sizes
    data = bytearray(path.read_bytes())
    at = data.index(b"data")
    with open(path, "r+b") as f:
        f.truncate(at + 8 + frames)
        f.seek(at + 4)
        f.write(frames.to_bytes(4, "little"))
        f.seek(4)
        f.write((at + frames).to_bytes(4, "little"))
    assert os.path.getsize(path) > limits.SOUND_SECONDS_MAX * rate
    with pytest.raises(SoundError, match=r"long\.wav: lasts 960\.0 s, over the 900 s"):
        load_sound(path)
