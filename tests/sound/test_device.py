"""Playing on the sound device (puppet.sound.device): the scheduler puts the sound's samples at
the DAC times PortAudio reports, and a machine without a device plays silent with a message."""

from __future__ import annotations

import numpy as np
import soundfile as sf

from puppet.sound import load_sound, take_window
from puppet.sound.device import NO_DEVICE, BlockScheduler, DevicePlayer

RATE = 48000


def test_blocks_at_dac_times_are_the_sound_under_the_take(clicks):
    """Blocks of irregular sizes at the DAC times a stream would report: concatenated, they are
    the take's window sample for sample (pre-roll: silence before time 0)."""
    track = clicks.click_track(RATE, seconds=2.0)
    offset_s, take_zero = 0.3, 100.0  # the stream clock reads 100 s at take time 0
    scheduler = BlockScheduler(track, RATE, offset_s)
    sizes = np.random.default_rng(1).integers(64, 1024, size=200)
    start = take_zero - 0.25  # pre-roll: the stream runs a quarter second before time 0
    played, at = [], 0
    block = np.empty((1024, 1), np.float32)
    silent_before = scheduler.fill(block[:256], start)  # not started yet: silence
    assert silent_before is None and not block[:256].any()
    scheduler.take_zero = take_zero
    for n in sizes:
        out = block[:n]
        scheduler.fill(out, start + at / RATE)
        played.append(out.copy())
        at += n
    played = np.concatenate(played)
    expected = take_window(track, RATE, offset_s, -0.25, at / RATE)
    np.testing.assert_array_equal(played, expected)
    assert clicks.lag_samples(played[:, 0], expected[:, 0]) == 0


def test_stop_silences_the_next_block(clicks):
    scheduler = BlockScheduler(clicks.click_track(RATE), RATE, 0.0)
    scheduler.take_zero = 0.0
    out = np.empty((480, 1), np.float32)
    assert scheduler.fill(out, 0.25) == 12000 and out.any()
    scheduler.stopped = True
    assert scheduler.fill(out, 0.26) is None and not out.any()


def test_no_device_plays_silent_with_a_message(tmp_path, clicks):
    path = tmp_path / "voice.wav"
    sf.write(path, clicks.click_track(RATE), RATE)
    player = DevicePlayer(load_sound(path), 0.0)
    ready = player.prepare()
    if ready:  # a machine with a device: it really plays; stop it again
        player.start()
        player.stop()
        assert player.message is None
    else:
        assert player.message.startswith(NO_DEVICE)
        player.start()  # on the monotonic clock: nothing to play on, nothing raised
        player.stop()
    player.stop()
    assert player.scheduler.stopped
