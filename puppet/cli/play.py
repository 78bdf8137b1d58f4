"""``puppet play``: replay a take through the solver and renderer (deterministic)."""

from __future__ import annotations

import sys

import click

from puppet.cli.common import fail, make_sinks, open_take, print_summary


@click.command()
@click.argument("take")
@click.option("--rig", "rig_path", default=None, help="Rig to replay on (default: the take's).")
@click.option("--out", default=None, help="Video file to write.")
@click.option("--frames", default=None, help="Folder for PNG frames.")
@click.option("--speed", default=1.0, show_default=True, type=click.FloatRange(min=0.01),
              help="Playback speed factor.")
@click.option("--fps", default=30.0, show_default=True, help="Output frame rate.")
@click.option("--antialias", type=click.Choice(["msaa", "fxaa", "none"]), default="msaa",
              show_default=True, help="Offline: MSAA by default, whatever the renderer.")
def play(take: str, rig_path: str | None, out: str | None, frames: str | None, speed: float,
         fps: float, antialias: str) -> None:
    """Replay a take through the solver and renderer (deterministic).

    \b
    Example:
      puppet play take.mcap --out take.mp4 --speed 0.5
    """
    from puppet.replay import play_take

    if not out and not frames:
        fail("nothing to write: give --out VIDEO and/or --frames FOLDER")
    rig, reader = open_take(take, rig_path)
    sinks = make_sinks(out, frames, fps)
    bar = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = click.progressbar(length=total, label="play", file=sys.stderr)
            bar.__enter__()
        bar.update(1)

    try:
        summary = play_take(rig, reader, sinks, fps=fps, speed=speed, antialias=antialias,
                            progress=progress)
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
        for sink in sinks:
            sink.close()
    print_summary(summary, False, extra={"take": take, "video": out} if out else {"take": take})


COMMANDS = (play,)
