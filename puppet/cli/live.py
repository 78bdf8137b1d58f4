"""``puppet live``: read the puppet, solve and render until Ctrl-C (optionally recording)."""

from __future__ import annotations

import click

from puppet.cli.common import StopFlag, load_rig, make_sinks, print_summary, start_reader, take_writer


@click.command()
@click.option("--rig", "rig_path", required=True, help="Rig file (TOML).")
@click.option("--port", required=True, help="Serial port, e.g. /dev/ttyUSB0 or hw-sim's pty.")
@click.option("--baud", default=1_000_000, show_default=True, help="Bus baud rate.")
@click.option("--record", "take_path", default=None, help="Also record a take here (.mcap).")
@click.option("--force", is_flag=True, help="Replace an existing take file (--record).")
@click.option("--out", default=None, help="Video file to write.")
@click.option("--frames", default=None, help="Folder for PNG frames.")
@click.option("--seconds", default=None, type=float, help="Stop after this long (default: Ctrl-C).")
@click.option("--fps", default=30.0, show_default=True, help="Video frame rate.")
@click.option("--antialias", type=click.Choice(["auto", "msaa", "fxaa", "none"]), default="auto",
              show_default=True, help="auto: MSAA on a GPU, FXAA on a software renderer.")
def live(rig_path: str, port: str, baud: int, take_path: str | None, out: str | None,
         frames: str | None, seconds: float | None, fps: float, antialias: str,
         force: bool) -> None:
    """Read the puppet, solve and render live until Ctrl-C.

    \b
    Example:
      puppet live --rig my.toml --port /dev/ttyUSB0 --record take.mcap --out live.mp4
    """
    from puppet.pipeline import Pipeline, run_live
    from puppet.take import BackgroundTakeWriter

    rig = load_rig(rig_path)
    sinks = make_sinks(out, frames, fps)
    stop = StopFlag()
    with Pipeline(rig, render=bool(sinks), overlay=True, antialias=antialias) as pipeline:
        source = start_reader(rig, port, baud)
        try:
            # On its own thread: a periodic fsync must not stall a frame.
            recorder = (BackgroundTakeWriter(take_writer(take_path, rig, force=force))
                        if take_path else None)
            try:
                summary = run_live(pipeline, source, seconds=seconds, sinks=sinks, video_fps=fps,
                                   recorder=recorder, should_stop=stop)
            finally:
                if recorder is not None:
                    recorder.close()
        finally:
            for sink in sinks:
                sink.close()
            source.stop()
    print_summary(summary, False, extra={"take": take_path} if take_path else None)


COMMANDS = (live,)
