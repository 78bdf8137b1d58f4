"""``puppet play``: replay a take through the solver and renderer (deterministic)."""

from __future__ import annotations

import sys

import click

from puppet import limits
from puppet.cli.common import (InRange, fail, force_option, layer_options, open_take, rig_files,
                               run_session, say)
from puppet.cli.blender import link_option
from puppet.cli.view import view_option


@click.command()
@click.argument("take")
@click.option("--rig", "rig_path", default=None, help="Rig to replay on (default: the take's).")
@click.option("--out", default=None, help="Video file to write.")
@click.option("--frames", default=None, help="Folder for PNG frames.")
@click.option("--speed", default=1.0, show_default=True, type=InRange(limits.SPEED),
              help="Playback speed factor.")
@click.option("--fps", default=30.0, show_default=True, type=InRange(limits.FPS),
              help=f"Frame rate of the video and frames ({limits.FPS}).")
@click.option("--antialias", type=click.Choice(["msaa", "fxaa", "none"]), default="msaa",
              show_default=True, help="Offline: MSAA by default, whatever the renderer.")
@click.option("--sound", "sound_path", default=None, metavar="FILE",
              help="Sound (WAV, FLAC, OGG, MP3) muxed into --out at the take's offset (default: "
                   "the take's own, found by its hash at its path or beside the take).")
@layer_options()
@view_option
@link_option
@force_option
def play(take: str, rig_path: str | None, out: str | None, frames: str | None, speed: float,
         fps: float, antialias: str, view_address: str | None, link_address: str | None,
         force: bool, sound_path: str | None, layers) -> None:
    """Replay a take through the solver and renderer (deterministic).

    A video or PNG frames estimated over 16 GiB (puppet.limits.EXPORT_BYTES, as every export: a
    long take or shot at a high --fps) are refused before anything is written, unless --force.

    \b
    Example:
      puppet play take.mcap --out take.mp4 --speed 0.5
      puppet play take.mcap --view       pause, scrub and change speed in the browser
      puppet play take.mcap --link       into Blender (the puppet_link add-on), on the clock
    """
    from puppet.replay import PLAY_SIZE
    from puppet.session import Session
    from puppet.session import outputs as o
    from puppet.session.sources import TakeFrames, TakeOnClock
    from puppet.take import Playback

    if sound_path is not None and out is None:
        fail("--sound is muxed into the video: give --out VIDEO")
    if view_address is not None and link_address is not None:
        fail("--view and --link: pick one for a play (both work on live and demo)")
    if not out and not frames and view_address is None and link_address is None:
        fail("nothing to write: give --out VIDEO and/or --frames FOLDER (or watch it: --view)")
    rig, reader = open_take(take, rig_path)
    outputs = []
    if out:
        sound, offset_s, timecode = _sound(reader, sound_path)
        outputs.append(o.Video(out, fps, force=force, sound=sound, sound_offset_s=offset_s,
                               sound_speed=speed, timecode=timecode, tell=say))
    if frames:
        outputs.append(o.Frames(frames))
    bar = None
    if view_address is not None:  # the take on the wall clock, driven from the page
        from puppet.take.markers import read_markers

        playback = Playback.of_take(reader, rig.servo_map.ids, rig=rig, layers=layers)
        marks = [(playback.play_s(t), name) for t, name in read_markers(take)]
        source = TakeOnClock(playback, speed=speed, markers=marks)
        outputs.append(o.View(view_address, mode="play", tell=say))
        pipeline = {"overlay": True, "live": True}
        on_frame = None
    else:  # the export's frames at --fps: as fast as possible, or on the clock into Blender
        playback = Playback.of_take(reader, rig.servo_map.ids, fps=fps,
                                    speed=1.0 if link_address is not None else speed, rig=rig,
                                    layers=layers)
        source = TakeFrames(playback, fps=fps, speed=speed, paced=link_address is not None)
        # before anything is written: the export's size rule (puppet.limits.EXPORT_BYTES)
        if out:
            _check_size("mp4", out, "the --out video", len(source), fps, force)
        if frames:
            _check_size("png", frames, "the --frames PNGs", len(source), fps, force)
        if link_address is not None:
            outputs.append(o.Link(link_address, rig, fps=fps, take=reader.path.stem,
                                  sound=_link_sound(reader), tell=say))
        pipeline = {"overlay": True, "antialias": antialias, "live": False,
                    "width": PLAY_SIZE[0], "height": PLAY_SIZE[1]}
        bar = click.progressbar(length=len(source), label="play", file=sys.stderr)
        on_frame = lambda done: bar.update(1)  # noqa: E731
    session = Session(rig, source, outputs, inputs=[take, *rig_files(rig)], video_fps=fps,
                      on_frame=on_frame, tell=say, pipeline=pipeline)
    if bar is None:
        run_session(session, extra=lambda _run: {"take": take})
        return
    with bar:
        session.run()
    if session.stopped_by is not None:
        say(f"stopped by {session.stopped_by} after {session.summary.frames} of {len(source)} "
            "frames; the outputs hold those frames")
    from puppet.cli.common import print_summary

    print_summary(session.summary, False, extra={"take": take, **session.report()})


def _check_size(kind: str, path: str, what: str, frames: int, fps: float, force: bool) -> None:
    """Refuse, unless ``force``, play's output ``path`` (``kind``: "mp4" or "png", ``what``:
    its option as the message names it) whose estimated size is over the export's limit."""
    from puppet.export.run import check_size, estimated_bytes
    from puppet.replay import PLAY_SIZE

    width, height = PLAY_SIZE
    check_size(path, what, estimated_bytes(kind, frames, pixels=width * height),
               f"{frames} frames of {width}x{height} at {fps:g} fps", force, "--fps (or raise --speed)")


def _sound(reader, sound_path: str | None):
    """(sound, offset_s, start timecode) for the video: the take's own sound (or --sound FILE);
    a missing one plays silent with one warning (at a --speed other than 1 the video's sound is
    played at that speed: ``puppet.sound.mux``)."""
    from puppet.sound import sound_for_take

    timecode = reader.metadata.timecode
    if sound_path is None and reader.metadata.sound is None:
        return None, 0.0, timecode
    sound, offset_s, warning = sound_for_take(reader, sound_path)
    if warning is not None:
        say(f"warning: {warning}")
    return sound, offset_s, timecode


def _link_sound(reader):
    """(path, offset_s) of the take's sound for the Blender link, or None (no sound; a missing
    one is said once: Blender plays silent)."""
    from puppet.sound import find_take_sound

    ref = reader.metadata.sound
    sound, warning = find_take_sound(ref, reader.path)
    if warning is not None:
        say(f"warning: {warning}")
    return None if sound is None else (sound.path, ref.offset_s)


COMMANDS = (play,)
