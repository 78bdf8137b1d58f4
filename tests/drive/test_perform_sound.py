"""``puppet perform --sound``: the sound plays with the motors (issue sound). This machine has no
sound device, so PortAudio is stood in for by a stream that records what it is asked: the
stream runs (pre-rolled) before the playback, the take's time 0 is set on its clock when the
playback starts, and it is stopped when the motors stop, before torque goes off."""

from __future__ import annotations

import time

import numpy as np
import soundfile
from click.testing import CliRunner

import hw_sim
import puppet.drive
from puppet.cli import main

EVENTS: list[tuple[str, float]] = []


class _Stream:
    """A PortAudio output stream that plays nothing and notes start and abort."""

    latency = 0.01

    def __init__(self, samplerate, channels, dtype, device, latency, callback):
        self.callback = callback

    @property
    def time(self) -> float:
        return time.monotonic()

    def start(self):
        EVENTS.append(("stream start", time.monotonic()))

    def abort(self):
        EVENTS.append(("stream abort", time.monotonic()))

    def close(self):
        pass


class _FakeSoundDevice:
    OutputStream = _Stream
    PortAudioError = OSError


def test_perform_plays_the_sound_from_the_playback_and_stops_it_with_the_motors(
        tmp_path, rig, wave_take, monkeypatch):
    import puppet.sound.device as device

    EVENTS.clear()
    monkeypatch.setattr(device, "_sounddevice", lambda: (_FakeSoundDevice, None))
    started = []
    original_start = device.DevicePlayer.start

    def start(self, take_zero=None):
        EVENTS.append(("take zero", time.monotonic()))
        started.append(original_start(self, take_zero))
        return started[-1]

    monkeypatch.setattr(device.DevicePlayer, "start", start)
    perform = puppet.drive.perform

    def watched(*args, on_phase=None, **kwargs):
        def phase(name):
            EVENTS.append((f"phase {name}", time.monotonic()))
            on_phase(name)
        return perform(*args, on_phase=phase, **kwargs)

    monkeypatch.setattr(puppet.drive, "perform", watched)
    sound = tmp_path / "voice.wav"
    soundfile.write(sound, np.zeros((48000, 1), np.float32), 48000)
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        result = CliRunner().invoke(main, ["perform", str(wave_take), "--port", bus.port,
                                           "--yes", "--latency-ms", "20", "--watchdog-ms", "2000",
                                           "--sound", str(sound)])
    assert result.exit_code == 0, result.output
    names = [name for name, _ in EVENTS]
    assert names.index("stream start") < names.index("phase playback") < names.index("take zero")
    # the sound stops in the same step as the motors' last goal: nothing between the two
    assert names[names.index("phase stop") + 1] == "stream abort", names
    at = dict(EVENTS)
    assert started and started[0] <= at["take zero"] + 1e-3  # time 0 on the stream's clock, now
