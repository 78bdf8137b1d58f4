"""``puppet blender addon``: write the Blender add-on; and the ``--link`` option the live, demo
and play commands share (stream each solve to Blender, ``puppet.link``)."""

from __future__ import annotations

import time
from pathlib import Path

import click

link_option = click.option(
    "--link", "link_address", is_flag=False, flag_value="", default=None, metavar="[HOST:]PORT",
    help="Stream each solve to Blender's puppet_link add-on (default 127.0.0.1:9100; another "
         "host prints a token the add-on needs).")


def open_link(address: str | None, rig, *, fps: float | None = None, take: str | None = None):
    """Bind the link's address now (a taken port fails before any hardware is touched) and say
    where it listens; returns the Link (attach it to the pipeline). fps: the take's rate (play);
    live and demo give the loop's when they attach. take: the take's name (the add-on names
    the recording's action after it)."""
    from puppet.link import Link

    link = Link(address, rig, fps=fps or 0.0, take=take)
    click.echo(f"link: listening on {link.where()}", err=True)
    return link


def report_link(link) -> dict:
    """The link's line for the run summary (``print_summary``'s extra)."""
    return {"link": link.text()}


def paced(frames, fps: float, speed: float, should_stop):
    """The readings of ``frames`` (a Playback) on the wall clock: frame k is handed out at
    start + k / (fps × speed) (never early; a late one at once)."""
    start = time.monotonic()
    for k, reading in enumerate(frames):
        wait = start + k / (fps * speed) - time.monotonic()
        while wait > 0 and not should_stop():
            time.sleep(min(wait, 0.1))
            wait = start + k / (fps * speed) - time.monotonic()
        yield k, reading


def play_to_link(take: str, rig_path: str | None, address: str, *, speed: float, fps: float,
                 out: str | None, frames_dir: str | None, force: bool) -> None:
    """``puppet play TAKE --link``: wait for a client, then solve the take's frames (the
    export's: ``puppet.take.Playback`` at ``fps``) on the wall clock at ``speed`` and stream each
    one with its take time k / fps; --out / --frames get the frames too."""
    from puppet.cli.common import (StopFlag, close_sinks, make_sinks, open_take, print_summary,
                                   rig_files)
    from puppet.export.run import take_frames
    from puppet.loop import Pipeline, run_frames

    rig, reader = open_take(take, rig_path)
    frames = take_frames(rig, reader, fps)
    link = open_link(address, rig, fps=fps, take=Path(take).stem)
    stop = StopFlag()
    try:
        sinks = make_sinks(out, frames_dir, fps, inputs=[take, *rig_files(rig)], force=force)
        with Pipeline(rig, render=bool(sinks)) as pipeline:
            link.attach(pipeline)
            click.echo("link: waiting for a client (Ctrl-C stops)", err=True)
            while link.clients_seen == 0 and not stop():
                time.sleep(0.05)
            current = {}

            def readings():
                for k, reading in paced(frames, fps, speed, stop):
                    current["take_s"] = k / fps
                    current["shown"] = _Stamp(time.monotonic_ns())  # the reading -> applied clock
                    yield reading

            def on_frame(solved) -> None:
                link.frame(solved, current["shown"], take_s=current["take_s"])

            try:
                summary = run_frames(pipeline, readings(), sinks=sinks, on_frame=on_frame,
                                     should_stop=stop)
            except BaseException:
                close_sinks(sinks, failed=True)
                raise
            close_sinks(sinks)
    finally:
        link.close()
    print_summary(summary, False, extra={"take": take, **report_link(link)})


class _Stamp:
    """A reading's time alone (what ``Link.frame`` reads of it)."""

    def __init__(self, t_ns: int):
        self.t_ns = t_ns


@click.group()
def blender() -> None:
    """Blender: the live link's add-on, and a rig's character to import."""


@blender.command()
@click.option("--out", default="puppet_link.zip", show_default=True,
              help="The add-on's zip file (install it in Blender's preferences).")
@click.option("--force", is_flag=True, help="Replace an existing file of another kind.")
def addon(out: str, force: bool) -> None:
    """Write the Blender add-on that receives ``--link`` (install: Edit > Preferences >
    Add-ons > Install from Disk, pick the zip, tick "puppet link").

    \b
    Example:
      puppet blender addon --out puppet_link.zip
    """
    from puppet.link.addon import write_addon

    path = write_addon(out, force=force)
    click.echo(f"add-on: {path}")


@blender.command()
@click.option("--rig", "rig_path", default=None, metavar="RIG",
              help="The rig file (default: the built-in critter).")
@click.option("--out", default="character.glb", show_default=True,
              help="The character's glTF binary (.glb) to import in Blender.")
@click.option("--force", is_flag=True, help="Replace an existing file of another kind.")
def character(rig_path: str | None, out: str, force: bool) -> None:
    """Write the rig's character at rest (its mesh, its skin, every joint) as a .glb for
    Blender: File > Import > glTF 2.0, then the add-on drives its armature with --link.

    \b
    Example:
      puppet blender character --out critter.glb     # the built-in critter
    """
    from puppet.cli.common import rig_files
    from puppet.export.character import write_character
    from puppet.rig import builtin, load_rig

    rig = builtin() if rig_path is None else load_rig(rig_path)
    path = write_character(rig, out, inputs=rig_files(rig), force=force)
    click.echo(f"character: {path} ({rig.name}, {len(rig.skeleton.names)} joints)")


COMMANDS = (blender,)
