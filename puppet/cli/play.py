"""``puppet play``: replay a take through the solver and renderer (deterministic)."""

from __future__ import annotations

import sys

import click

from puppet import limits
from puppet.cli.common import (InRange, StopFlag, close_sinks, fail, force_option, make_sinks,
                               open_take, print_summary, rig_files)
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
@view_option
@link_option
@force_option
def play(take: str, rig_path: str | None, out: str | None, frames: str | None, speed: float,
         fps: float, antialias: str, view_address: str | None, link_address: str | None,
         force: bool, sound_path: str | None) -> None:
    """Replay a take through the solver and renderer (deterministic).

    \b
    Example:
      puppet play take.mcap --out take.mp4 --speed 0.5
      puppet play take.mcap --view       pause, scrub and change speed in the browser
      puppet play take.mcap --link       into Blender (the puppet_link add-on), on the clock
    """
    from puppet.replay import play_take

    if sound_path is not None and out is None:
        fail("--sound is muxed into the video: give --out VIDEO")
    if view_address is not None and link_address is not None:
        fail("--view and --link: pick one for a play (both work on live and demo)")
    if link_address is not None:
        from puppet.cli.blender import play_to_link

        play_to_link(take, rig_path, link_address, speed=speed, fps=fps, out=out,
                     frames_dir=frames, force=force)
        return

    if view_address is not None:
        from puppet.cli.view import play_in_view

        play_in_view(take, rig_path, out, frames, speed, fps, view_address, force=force)
        return
    if not out and not frames:
        fail("nothing to write: give --out VIDEO and/or --frames FOLDER (or watch it: --view)")
    rig, reader = open_take(take, rig_path)
    sound, offset_s, timecode = _sound(reader, sound_path, out, speed)
    sinks = make_sinks(out, frames, fps, inputs=[take, *rig_files(rig)], force=force,
                       sound=sound, sound_offset_s=offset_s, timecode=timecode)
    stop = StopFlag()  # Ctrl-C or SIGTERM: stop after this frame, finish the video (playable)
    bar = None
    total = 0

    def progress(done: int, frames_in_all: int) -> None:
        nonlocal bar, total
        if bar is None:
            total = frames_in_all
            bar = click.progressbar(length=total, label="play", file=sys.stderr)
            bar.__enter__()
        bar.update(1)

    try:
        summary = play_take(rig, reader, sinks, fps=fps, speed=speed, antialias=antialias,
                            progress=progress, should_stop=stop)
    except BaseException:
        close_sinks(sinks, failed=True)
        raise
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    close_sinks(sinks)
    for note in (n for sink in sinks for n in getattr(sink, "notes", ())):
        click.echo(f"warning: {note}", err=True)
    if stop():
        click.echo(f"stopped by {stop.signal_name} after {summary.frames} of {total} frames; "
                   "the outputs hold those frames", err=True)
    print_summary(summary, False, extra={"take": take, "video": out} if out else {"take": take})

def _sound(reader, sound_path: str | None, out: str | None, speed: float):
    """(sound, offset_s, start timecode) for the video: the take's own sound (or --sound FILE);
    a missing one, or a --speed other than 1, plays silent with one warning."""
    from puppet.sound import sound_for_take

    timecode = reader.metadata.timecode
    if out is None or (sound_path is None and reader.metadata.sound is None):
        return None, 0.0, timecode
    if speed != 1.0:
        click.echo(f"warning: --speed {speed:g}: the video is silent (its sound plays at speed 1 "
                   "only)", err=True)
        return None, 0.0, timecode
    sound, offset_s, warning = sound_for_take(reader, sound_path)
    if warning is not None:
        click.echo(f"warning: {warning}", err=True)
    return sound, offset_s, timecode


COMMANDS = (play,)
