"""Exports keep the sync: glTF (extras), USD (customLayerData, time codes) and BVH (a comment)
carry the take's sound (file, hash, offset, rate), the frame rate and the start timecode; and
``puppet play --out`` muxes the take's sound, or plays silent with one warning."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pygltflib
import pytest
import soundfile as sf

from puppet.export import Outputs, export_take
from puppet.reading import Reading
from puppet.sound import load_sound, sound_ref
from puppet.take import TakeReader, TakeWriter
from puppet.timecode import StartTimecode

READINGS = 16  # half a second at 30 readings/s


@pytest.fixture(scope="module")
def critter():
    from puppet.rig import builtin

    return builtin()


def write_take(path, rig, **kw):
    k = len(rig.servo_map)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids],
                    models=dict(rig.servo_map.models), rig_map_text="", calibration_text="",
                    rig_name=rig.name, **kw) as writer:
        for i in range(READINGS):
            ticks = (rig.servo_map.zero + 300 * np.sin(0.2 * i + np.arange(k))).astype(np.int32)
            writer.write(Reading(1_000_000_000 + round(i * 1e9 / 30), rig.servo_map.ids, ticks,
                                 np.ones(k, bool)))
    return path


@pytest.fixture
def voiced_take(tmp_path, critter, clicks):
    sound_path = tmp_path / "line 1.wav"
    sf.write(sound_path, clicks.click_track(48000, seconds=2.0), 48000)
    ref = sound_ref(load_sound(sound_path), offset_s=0.4)
    take = write_take(tmp_path / "take.mcap", critter, sound=ref,
                      timecode=StartTimecode("01:00:00:00", "25"))
    return take, ref


def test_gltf_usd_bvh_carry_the_sound_and_timecode(tmp_path, critter, voiced_take):
    take, ref = voiced_take
    files = Outputs(gltf=tmp_path / "a.glb", usd=tmp_path / "a.usda", bvh=tmp_path / "a.bvh")
    export_take(critter, TakeReader(take), files, fps=25.0)
    expected = {"puppet_fps": 25.0, "puppet_frame_start": 1, "puppet_sound_file": "line 1.wav",
                "puppet_sound_path": ref.path, "puppet_sound_sha256": ref.sha256,
                "puppet_sound_rate": 48000, "puppet_sound_offset_s": 0.4,
                "puppet_sound_frame": -9.0,  # 1 - 0.4 s x 25 fps: sample 0 plays 10 frames early
                "puppet_timecode_start": "01:00:00:00", "puppet_timecode_rate": "25"}
    gltf = pygltflib.GLTF2().load_binary(str(files.gltf))
    for extras in (gltf.scenes[gltf.scene].extras, gltf.animations[0].extras):
        assert {k: extras[k] for k in expected} == expected
    from pxr import Usd

    stage = Usd.Stage.Open(str(files.usd))
    assert dict(stage.GetRootLayer().customLayerData) == expected
    assert stage.GetTimeCodesPerSecond() == 25.0 and stage.GetStartTimeCode() == 1.0
    lines = files.bvh.read_text().splitlines()
    assert lines[0] == "HIERARCHY"
    assert lines[1].startswith("# puppet ")
    assert json.loads(lines[1][len("# puppet "):]) == expected


def test_a_clip_carries_the_sound_and_timecode_of_its_in_point(tmp_path, critter, voiced_take):
    """A clip from take time 0.2 s: its frame 1 is there, so the sound plays from 0.4 + 0.2 s
    into the file's frame 1 and the timecode is 5 frames (at 25 fps) on."""
    take, _ = voiced_take
    out = Outputs(gltf=tmp_path / "clip.glb")
    export_take(critter, TakeReader(take), out, fps=25.0, clip=(0.2, 0.4, False))
    extras = pygltflib.GLTF2().load_binary(str(out.gltf)).scenes[0].extras
    assert extras["puppet_sound_offset_s"] == pytest.approx(0.6)
    assert extras["puppet_sound_frame"] == pytest.approx(1 - 0.6 * 25)
    assert extras["puppet_timecode_start"] == "01:00:00:05"


def test_the_timecode_follows_the_export_rate(tmp_path, critter, voiced_take):
    take, _ = voiced_take
    out = Outputs(gltf=tmp_path / "b.glb")
    export_take(critter, TakeReader(take), out, fps=30.0)
    extras = pygltflib.GLTF2().load_binary(str(out.gltf)).scenes[0].extras
    assert (extras["puppet_timecode_start"], extras["puppet_timecode_rate"]) == ("01:00:00:00", "30")
    assert extras["puppet_sound_frame"] == pytest.approx(1 - 0.4 * 30)


def test_a_take_without_sound_exports_as_before(tmp_path, critter):
    take = write_take(tmp_path / "plain.mcap", critter)
    out = Outputs(gltf=tmp_path / "c.glb", bvh=tmp_path / "c.bvh")
    export_take(critter, TakeReader(take), out, fps=30.0)
    extras = pygltflib.GLTF2().load_binary(str(out.gltf)).scenes[0].extras
    assert not any(k.startswith(("puppet_sound", "puppet_timecode")) for k in extras)
    assert "# puppet" not in out.bvh.read_text()


def test_the_sound_is_an_input_no_export_may_overwrite(tmp_path, critter, voiced_take):
    from puppet.atomic import OutputError

    take, ref = voiced_take
    with pytest.raises(OutputError, match="also an input"):
        export_take(critter, TakeReader(take), Outputs(bvh=ref.path, force=True), fps=30.0)


def run(*args):
    return subprocess.run(["puppet", *map(str, args)], capture_output=True, text=True, timeout=300)


def decoded_audio(path) -> np.ndarray:
    import imageio_ffmpeg

    done = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path),
                           "-map", "0:a", "-f", "f32le", "-ac", "1", "-ar", "48000", "-"],
                          capture_output=True, check=True)
    return np.frombuffer(done.stdout, np.float32)


def test_play_out_muxes_the_takes_sound_or_warns_once(tmp_path, voiced_take, clicks):
    take, ref = voiced_take
    video = tmp_path / "take.mp4"
    result = run("play", take, "--out", video, "--fps", 25)
    assert result.returncode == 0, result.stderr
    assert result.stderr.count("cut at the video's end") == 1
    audio = decoded_audio(video)
    assert len(audio) == round(13 / 25 * 48000)  # 0.5 s of take: 13 frames at 25 fps
    from puppet.sound import take_window

    sound = load_sound(ref.path)
    expected = take_window(sound.samples, 48000, 0.4, 0.0, 13 / 25)[:, 0]
    assert clicks.lag_samples(audio, expected) == 0
    # the sound is an input: never the video
    refused = run("play", take, "--out", ref.path, "--force")
    assert refused.returncode == 1 and "also an input" in refused.stderr
    assert "Traceback" not in refused.stderr
    # the sound gone: the video is silent, said once
    (tmp_path / "line 1.wav").rename(tmp_path / "moved.wav")
    silent = tmp_path / "silent.mp4"
    result = run("play", take, "--out", silent, "--fps", 25)
    assert result.returncode == 0, result.stderr
    assert result.stderr.count("playing silent") == 1
    import imageio_ffmpeg

    info = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(silent)],
                          capture_output=True, text=True).stderr
    assert "Video:" in info and "Audio:" not in info


def test_a_bad_sound_is_an_error_naming_it(tmp_path, voiced_take):
    take, _ = voiced_take
    bad = tmp_path / "bad.mp3"
    bad.write_bytes(b"not a sound at all" * 64)
    for args in (("export", take, "--bvh", tmp_path / "o.bvh", "--sound", bad),
                 ("play", take, "--out", tmp_path / "o.mp4", "--sound", bad)):
        result = run(*args)
        assert result.returncode == 1, result.stderr
        assert f"Error: {bad}: cannot decode it as a sound" in result.stderr
        assert "Traceback" not in result.stderr
    assert not (tmp_path / "o.bvh").exists() and not (tmp_path / "o.mp4").exists()
    result = run("play", take, "--sound", bad, "--frames", tmp_path / "f")
    assert result.returncode == 1 and "--sound is muxed into the video: give --out" in result.stderr
