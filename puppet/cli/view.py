"""``puppet view``: the rig alone in the browser, posed only by dragged point handles (no bus);
and the ``--view`` option the live, demo and play commands share."""

from __future__ import annotations

import logging

import click

from puppet import limits
from puppet.cli.common import InRange, StopFlag, load_rig

view_option = click.option(
    "--view", "view_address", is_flag=False, flag_value="", default=None, metavar="[HOST:]PORT",
    help="Watch live in a browser (default 127.0.0.1:8765; another host gets a URL with a token); "
         "prints the URL.")


class _ViewLogFormat(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        return f"warning: {text}" if record.levelno >= logging.WARNING else text


def open_view(address: str | None, *, mode: str, take_factory=None, takes_dir=".", keys=None):
    """Bind the live view's address now (a taken port fails before any hardware is touched),
    route its log to stderr, print its URL; returns the View (attach it to the pipeline).
    keys: a KeyDesk (``puppet keys --view``)."""
    from puppet.view import View

    view = View(address, mode=mode, take_factory=take_factory, takes_dir=takes_dir, keys=keys)
    logger = logging.getLogger("puppet.view")
    if not logger.handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(_ViewLogFormat())
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False
    click.echo(f"view: {view.url}", err=True)
    return view


def take_factory_for(rig):
    """path -> an open BackgroundTakeWriter for the rig (the page's record button)."""
    from puppet.cli.common import take_writer
    from puppet.take import BackgroundTakeWriter

    return lambda path: BackgroundTakeWriter(take_writer(str(path), rig))


@click.command()
@click.option("--rig", "rig_path", default=None, help="Rig file (default: the built-in critter).")
@click.option("--address", "address", default="", metavar="[HOST:]PORT",
              help="Where to serve the page (default 127.0.0.1:8765).")
@click.option("--seconds", default=None, type=InRange(limits.SECONDS),
              help=f"Stop after this long ({limits.SECONDS}; default: Ctrl-C).")
@click.option("--size", default=(640, 480), show_default=True,
              type=(InRange(limits.FRAME_SIZE), InRange(limits.FRAME_SIZE)),
              help=f"Frame size: width and height, each {limits.FRAME_SIZE}.")
def view(rig_path: str | None, address: str, seconds: float | None, size: tuple[int, int]) -> None:
    """Show a rig in the browser in its rest pose; drag point handles to pose it (no bus).

    \b
    Example:
      puppet view --rig my.toml
    """
    from puppet.loop import Pipeline, run_live
    from puppet.view import RestSource

    live_view = open_view(address, mode="rig")
    try:
        rig = load_rig(rig_path)
        stop = StopFlag()
        with Pipeline(rig, overlay=True, width=size[0], height=size[1], live=True) as pipeline:
            source = RestSource(rig.servo_map.ids, rig.servo_map.zero)
            live_view.attach(pipeline, source=source)
            summary = run_live(pipeline, source, seconds=seconds, should_stop=stop, view=live_view)
    finally:
        live_view.close()
    click.echo(f"frames {summary.frames} in {summary.seconds:.1f} s; handles {len(live_view.handles())}")


COMMANDS = (view,)


def play_in_view(take: str, rig_path: str | None, out: str | None, frames: str | None,
                 speed: float, fps: float, view_address: str, *, force: bool = False) -> None:
    """``puppet play TAKE --view``: the take on the wall clock, paused, scrubbed and sped up from
    the page, until Ctrl-C; --out / --frames get the frames as shown."""
    from puppet.cli.common import make_sinks, open_take, print_summary, rig_files
    from puppet.loop import Pipeline, run_live
    from puppet.take import Playback
    from puppet.take.markers import read_markers
    from puppet.view import TakeSource

    live_view = open_view(view_address, mode="play")
    stop = StopFlag()  # before the page is served: a Ctrl-C from then on ends the run cleanly
    try:
        rig, reader = open_take(take, rig_path)
        playback = Playback.of_take(reader, rig.servo_map.ids, rig=rig)
        marks = [(playback.play_s(t), name) for t, name in read_markers(take)]
        source = TakeSource(playback, speed=speed, markers=marks)
        sinks = make_sinks(out, frames, fps, inputs=[take, *rig_files(rig)], force=force)
        try:
            with Pipeline(rig, overlay=True, live=True) as pipeline:
                live_view.attach(pipeline, source=source)
                summary = run_live(pipeline, source, sinks=sinks, video_fps=fps,
                                   should_stop=stop, view=live_view)
        finally:
            for sink in sinks:
                sink.close()
    finally:
        live_view.close()
    print_summary(summary, False, extra={"take": take})
