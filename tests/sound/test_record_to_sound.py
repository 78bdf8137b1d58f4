"""Performing to a sound through a live session (issue sound): `puppet record --sound
--count-in` counts in, records from the take's time 0, stores the sound's reference with its
offset (the sound's time at the first reading recorded) and a start timecode; `play --out` of
that take finds the sound and muxes it at that offset. Here there is no sound device: the
command says so once and plays silent."""

from __future__ import annotations

import subprocess
import sys

import soundfile

import hw_sim
from puppet.rig import builtin
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader

PUPPET = [sys.executable, "-m", "puppet.cli"]


def test_record_to_a_sound_with_a_count_in_stores_where_the_sound_was(tmp_path, clicks):
    sound = tmp_path / "voice.wav"
    soundfile.write(sound, clicks.click_track(48000, 4.0), 48000)
    before = sound.read_bytes()
    take = tmp_path / "t.mcap"
    rig = builtin()
    with hw_sim.serve(dict(rig.servo_map.models), motion="wave") as bus:
        done = subprocess.run([*PUPPET, "record", "--rig", str(BUILTIN_RIG), "--port", bus.port,
                               "--out", str(take), "--seconds", "1.5", "--count-in", "1",
                               "--sound", str(sound), "--sound-offset", "0.5"],
                              capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    said = done.stderr.splitlines()
    assert [line for line in said if line in ("1", "recording")] == ["1", "recording"], done.stderr
    assert sum("no sound device" in line for line in said) <= 1, done.stderr
    meta = TakeReader(take).metadata
    assert meta.sound is not None and meta.sound.name == "voice.wav"
    # the sound's time at the first reading: the given offset plus at most a few reading periods
    assert 0.5 <= meta.sound.offset_s < 0.5 + 0.1, meta.sound
    assert meta.timecode is not None
    assert sound.read_bytes() == before  # an input: never written over

    video = tmp_path / "v.mp4"
    played = subprocess.run([*PUPPET, "play", str(take), "--out", str(video), "--antialias", "none"],
                            capture_output=True, text=True, timeout=300)
    assert played.returncode == 0, played.stderr
    assert "playing silent" not in played.stderr, played.stderr
    probe = subprocess.run([_ffmpeg(), "-i", str(video)], capture_output=True, text=True)
    assert "Audio:" in probe.stderr, probe.stderr


def test_a_sound_that_cannot_be_decoded_is_refused_before_the_bus(tmp_path):
    bad = tmp_path / "voice.wav"
    bad.write_text("not a sound")
    done = subprocess.run([*PUPPET, "record", "--rig", str(BUILTIN_RIG), "--port",
                           "/dev/puppet-no-such-port", "--out", str(tmp_path / "t.mcap"),
                           "--sound", str(bad)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert str(bad) in done.stderr and "puppet-no-such-port" not in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "t.mcap").exists()


def _ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()
