"""Muxing a take's sound into a finished MP4 video (ffmpeg, the binary imageio-ffmpeg ships).

The audio track is exactly the video's length: the sound under the take (``puppet.sound.window``)
from its time 0 to count / fps, silence where the sound has none, the rest of a longer sound cut.
AAC's encoder priming (1024 samples) is hidden by the edit list ffmpeg writes, so a decoder's
first sample is the take's time 0 (checked after decoding, tests/sound/test_mux.py). The video
stream is copied, not encoded again; ``timecode`` writes the MP4's timecode track.

A video played at a speed other than 1 (``play --speed``) covers ``seconds · speed`` of the take:
the sound under it is played at that speed as tape does (its samples read at ``rate · speed``,
then resampled to ``rate`` by ffmpeg: the pitch follows the speed), so every click lands on the
frame of the motion it was recorded with. (A pitch-keeping stretch, ffmpeg's ``atempo``, moved
clicks by up to 4 frames at speed 0.2: its overlap-add repeats onsets.)
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import imageio_ffmpeg

from puppet.sound.errors import SoundError
from puppet.sound.window import take_window

AUDIO_CODEC = ["-c:a", "aac", "-b:a", "192k"]


def mux_sound(video: Path, out: Path, samples, rate: int, offset_s: float, seconds: float, *,
              timecode: str | None = None, source: str = "sound", speed: float = 1.0) -> None:
    """Write ``out``: the video stream of ``video`` with the sound under it.

    samples: (frames, channels) float32 sound; rate: Hz; offset_s: the sound's time at the
    video's first frame; seconds: the video's length (frames / fps); timecode: "HH:MM:SS:FF" of
    the first frame (";FF" drop-frame) or None; source: the sound's file, for messages; speed:
    take seconds per video second (the sound plays at that speed, see the module).
    Raises SoundError naming the sound when ffmpeg fails.
    """
    pcm = take_window(samples, rate, offset_s, 0.0, seconds * speed)
    channels = pcm.shape[1]
    stretch = ([] if speed == 1.0 else
               ["-af", f"asetrate={rate * speed:.6f},aresample={rate},apad", "-t", f"{seconds:.6f}"])
    command = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-v", "error", "-i", str(video),
               "-f", "f32le", "-ar", str(rate), "-ac", str(channels), "-i", "-",
               "-map", "0:v:0", "-map", "1:a:0", "-c:v", "copy", *stretch, *AUDIO_CODEC,
               *(["-timecode", timecode] if timecode else []), str(out)]
    try:
        done = subprocess.run(command, input=pcm.tobytes(), stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, check=False)
    except OSError as err:
        raise SoundError(source, f"cannot start ffmpeg to mux the sound: {err}") from None
    if done.returncode != 0:
        said = done.stderr.decode(errors="replace").strip().splitlines()
        raise SoundError(source, f"ffmpeg could not mux the sound into {out} (status "
                                 f"{done.returncode}){': ' + said[-1] if said else ''}")
