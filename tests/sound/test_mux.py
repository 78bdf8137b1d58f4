"""The video's sound (VideoSink(sound=...), puppet.sound.mux): a click track muxed at an offset
lands, after decoding the MP4 (AAC priming included), on the sample and the frame it should."""

from __future__ import annotations

import subprocess

import imageio_ffmpeg
import numpy as np
import pytest
import soundfile as sf

from puppet.render.sinks import VideoSink
from puppet.sound import load_sound, take_window
from puppet.timecode import StartTimecode

RATE = 48000
FPS = 30.0


def decoded_audio(path, rate=RATE) -> np.ndarray:
    """(n,) float32 mono: the MP4's sound as a player decodes it (edit list applied)."""
    done = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path),
                           "-map", "0:a", "-f", "f32le", "-ac", "1", "-ar", str(rate), "-"],
                          capture_output=True, check=True)
    return np.frombuffer(done.stdout, np.float32)


def decoded_brightness(path) -> np.ndarray:
    """(frames,) mean brightness of each decoded video frame."""
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    return np.array([np.frombuffer(f, np.uint8).reshape(h, w, 3).mean() for f in reader])


def ffmpeg_info(path) -> str:
    return subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                          capture_output=True, text=True).stderr


@pytest.mark.parametrize("offset_s", [0.515, -0.2])  # clicks inside frames, not on their edges
def test_clicks_land_on_their_frames(tmp_path, clicks, offset_s):
    """Frame k is white when a click starts in it (the motion event recorded with the click);
    the decoded sound has each click on that frame, and the whole track 0 samples off."""
    sound_path = tmp_path / "clicks.wav"
    sf.write(sound_path, clicks.click_track(RATE, seconds=3.0), RATE)
    sound = load_sound(sound_path)
    before = sound_path.read_bytes()
    n = 45  # 1.5 s of video: the sound is longer, so it is cut
    take_times = [c - offset_s for c in clicks.CLICK_TIMES_S if 0 <= c - offset_s < n / FPS]
    event_frames = {int(t * FPS) for t in take_times}
    out = tmp_path / "take.mp4"
    with VideoSink(out, FPS, sound=sound, sound_offset_s=offset_s) as video:
        for k in range(n):
            video.write(np.full((64, 64, 3), 255 if k in event_frames else 0, np.uint8))
    assert len(video.notes) == 1 and "cut at the video's end" in video.notes[0]
    audio = decoded_audio(out)
    assert len(audio) == round(n / FPS * RATE)  # exactly the video's length
    expected = take_window(sound.samples, RATE, offset_s, 0.0, n / FPS)[:, 0]
    assert clicks.lag_samples(audio, expected) == 0
    heard = clicks.onsets(audio, RATE)
    assert len(heard) == len(take_times)
    white = set(np.flatnonzero(decoded_brightness(out) > 128).tolist())
    assert white == event_frames
    assert {int(t * FPS) for t in heard} == event_frames
    assert np.max(np.abs(np.array(heard) - take_times)) < 1e-3  # the onset threshold's delay
    assert sound_path.read_bytes() == before


@pytest.mark.parametrize("fps, start, label", [
    (24000 / 1001, StartTimecode("01:00:00:00", "23.976"), "01:00:00:00"),
    (30000 / 1001, StartTimecode("00:09:59;29", "29.97"), "00:09:59;29"),
    (25.0, StartTimecode("10:00:00:00", "25"), "10:00:00:00"),
])
def test_timecode_track(tmp_path, fps, start, label):
    out = tmp_path / "tc.mp4"
    with VideoSink(out, fps, timecode=start) as video:
        for _ in range(4):
            video.write(np.zeros((32, 32, 3), np.uint8))
    info = ffmpeg_info(out)
    assert f"timecode        : {label}" in info and "tmcd" in info
    assert "Audio" not in info
    assert video.notes == []


def test_no_timecode_track_off_the_timecode_rates(tmp_path):
    out = tmp_path / "tc.mp4"
    with VideoSink(out, 60.0, timecode=StartTimecode("01:00:00:00", "30")) as video:
        video.write(np.zeros((32, 32, 3), np.uint8))
    assert "tmcd" not in ffmpeg_info(out) and "timecode  " not in ffmpeg_info(out)
    assert video.notes == [f"{out}: no timecode track: 60 fps is not a timecode rate (23.976, 24, "
                           "25, 29.97, 30)"]


@pytest.mark.parametrize("speed", [0.5, 2.0, 0.2])
def test_a_video_at_another_speed_keeps_its_clicks_on_their_frames(tmp_path, clicks, speed):
    """``play --speed``: video frame k shows take time k · speed / fps; the sound under it is
    played at that speed (tape-like), so each click is heard on the frame of its motion event."""
    sound_path = tmp_path / "clicks.wav"
    sf.write(sound_path, clicks.click_track(RATE, seconds=2.5), RATE)
    sound = load_sound(sound_path)
    n = 60
    covered = n / FPS * speed  # take seconds the video shows
    take_times = [c for c in clicks.CLICK_TIMES_S if c < covered]
    event_frames = {int(t / speed * FPS) for t in take_times}
    out = tmp_path / "take.mp4"
    with VideoSink(out, FPS, sound=sound, sound_speed=speed) as video:
        for k in range(n):
            video.write(np.full((64, 64, 3), 255 if k in event_frames else 0, np.uint8))
    audio = decoded_audio(out)
    assert abs(len(audio) - round(n / FPS * RATE)) <= 1024  # the video's length, to an AAC frame
    heard = clicks.onsets(audio, RATE)
    assert len(heard) == len(take_times), (heard, take_times)
    assert {int(t * FPS) for t in heard} == event_frames
    lag_s = np.array(heard) - np.array(take_times) / speed
    assert np.max(np.abs(lag_s)) < 1e-3 / min(speed, 1.0)  # the onset threshold's delay, slowed
    white = set(np.flatnonzero(decoded_brightness(out) > 128).tolist())
    assert white == event_frames
