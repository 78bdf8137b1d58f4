"""``puppet live``: read the puppet, solve and render until Ctrl-C (optionally recording)."""

from __future__ import annotations

from pathlib import Path

import click

from puppet import limits
from puppet.cli.common import (InRange, StopFlag, check_take_path, load_rig, make_sinks,
                               print_summary, rig_files, start_reader, take_writer)
from puppet.cli.blender import link_option, open_link, report_link
from puppet.cli.view import open_view, take_factory_for, view_option

READ_RATE_HZ = 500.0
"""Bus cycles per second in live (a read of every servo, and the actuators' goal write)."""


def report_actuators(source) -> None:
    """Say on stderr what the actuators' setup changed and their torque read back at the end."""
    for note in source.notes:
        click.echo(note, err=True)
    after = source.torque_after
    release = f"; `puppet release --port {source.port}` turns it off"
    if not after:
        ids = [int(i) for i in source.hook.ids]
        click.echo(f"warning: actuator servos {ids}: torque not confirmed off (no read back)"
                   + release, err=True)
        return
    on = sorted(i for i, v in after.items() if v != 0)
    if on:
        click.echo(f"warning: actuator servos {on}: torque not confirmed off (read back {after})"
                   + release, err=True)
    else:
        click.echo(f"actuators {sorted(after)}: torque off (read back)", err=True)


def _key_desk(rig, shot_path: str):
    """The KeyDesk of ``live --view --keys``: a new shot at ``puppet keys``' defaults, its
    outcomes said on the terminal."""
    from puppet.cli.common import take_header
    from puppet.cli.keys import DEFAULT_FPS, DEFAULT_STEP, say_outcome
    from puppet.keys.capture import KeyDesk, KeySession

    session = KeySession(shot_path, take_header(rig), fps=DEFAULT_FPS, step=DEFAULT_STEP)
    return KeyDesk(session, tell=say_outcome)


@click.command()
@click.option("--rig", "rig_path", required=True, help="Rig file (TOML).")
@click.option("--port", required=True, help="Serial port, e.g. /dev/ttyUSB0 or hw-sim's pty.")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
@click.option("--record", "take_path", default=None, help="Also record a take here (.mcap).")
@click.option("--force", is_flag=True, help="Replace an existing take file (--record), or an "
              "existing file of another kind at --out (an input, a device or a FIFO never).")
@click.option("--out", default=None, help="Video file to write.")
@click.option("--frames", default=None, help="Folder for PNG frames.")
@click.option("--seconds", default=None, type=InRange(limits.SECONDS),
              help=f"Stop after this long ({limits.SECONDS}; default: Ctrl-C).")
@click.option("--fps", default=30.0, show_default=True, type=InRange(limits.FPS),
              help=f"Frame rate of the video and frames ({limits.FPS}).")
@click.option("--antialias", type=click.Choice(["auto", "msaa", "fxaa", "none"]), default="auto",
              show_default=True, help="auto: MSAA on a GPU, FXAA on a software renderer.")
@click.option("--watchdog-ms", default=100.0, show_default=True, type=InRange(limits.WATCHDOG_MS),
              help=f"Actuator servos: their Bus Watchdog period ({limits.WATCHDOG_MS}).")
@click.option("--no-watchdog", is_flag=True,
              help="Drive actuators without the Bus Watchdog, also on a model that has none "
                   "(a host crash leaves them driving).")
@click.option("--keys", "shot_path", default=None,
              help="With --view: take key poses into this shot from the page (Space or its Key "
                   "button; timeline, onion skins) as `puppet keys --view` does, at its default "
                   "--fps and --step.")
@view_option
@link_option
def live(rig_path: str, port: str, baud: int, take_path: str | None, out: str | None,
         frames: str | None, seconds: float | None, fps: float, antialias: str,
         force: bool, shot_path: str | None, view_address: str | None,
         link_address: str | None, watchdog_ms: float, no_watchdog: bool) -> None:
    """Read the puppet, solve and render live until Ctrl-C.

    Servos with role = "actuator" in the rig file are driven to the angle the solve gives
    their joint (torque on while live runs, off on every way out).

    \b
    Example:
      puppet live --rig my.toml --port /dev/ttyUSB0 --record take.mcap --out live.mp4
      puppet live --rig my.toml --port /dev/ttyUSB0 --view     watch at the printed URL
      puppet live --rig my.toml --port /dev/ttyUSB0 --view --keys shot.mcap   key poses from the page
      puppet live --rig my.toml --port /dev/ttyUSB0 --link     into Blender (puppet_link add-on)
    """
    from puppet.drive.actuators import ActuationPlan, ActuatorHook, LiveActuation
    from puppet.loop import Pipeline, run_live
    from puppet.take import BackgroundTakeWriter

    rig = load_rig(rig_path)
    if shot_path is not None and view_address is None:
        raise click.UsageError("--keys takes keys from the page: add --view (or use `puppet keys`)")
    if take_path or shot_path:  # every output checked before the view, the bus or any file is touched
        from puppet.atomic import check_distinct

        check_distinct({"--record": take_path, "--out": out, "--keys": shot_path})
        for path in (take_path, shot_path):
            if path:
                check_take_path(path, rig, force=force)
    desk = _key_desk(rig, shot_path) if shot_path else None
    sinks = make_sinks(out, frames, fps, inputs=rig_files(rig), force=force)
    live_view = link = None
    if link_address is not None:  # bound before the bus is touched: a taken port fails first
        link = open_link(link_address, rig)
    if view_address is not None:  # bound before the bus is touched: a taken port fails first
        takes = Path(take_path).parent if take_path else Path(".")
        live_view = open_view(view_address, mode="live", take_factory=take_factory_for(rig),
                              takes_dir=takes, keys=desk)
    stop = StopFlag()
    try:
        with Pipeline(rig, render=bool(sinks) or live_view is not None, overlay=True,
                      antialias=antialias, live=True) as pipeline:
            plan = ActuationPlan.for_rig(rig, READ_RATE_HZ,
                                         watchdog_ms=0.0 if no_watchdog else watchdog_ms)
            actuation = LiveActuation(rig) if plan is not None else None
            source = start_reader(rig, port, baud, READ_RATE_HZ,
                                  hook=ActuatorHook(plan) if plan is not None else None)
            if actuation is not None:
                actuation.source = source
            try:
                # On its own thread: a periodic fsync must not stall a frame.
                recorder = (BackgroundTakeWriter(take_writer(take_path, rig, force=force))
                            if take_path else None)
                try:
                    if live_view is not None:
                        live_view.attach(pipeline, source=source, recorder=recorder)
                    if link is not None:
                        link.attach(pipeline)
                    summary = run_live(pipeline, source, seconds=seconds, sinks=sinks, video_fps=fps,
                                       recorder=recorder, should_stop=stop, view=live_view,
                                       after_solve=actuation and actuation.after_solve, link=link)
                finally:
                    if live_view is not None:
                        live_view.close()
                    if recorder is not None:
                        recorder.close()
            finally:
                for sink in sinks:
                    sink.close()
                source.stop()
                if plan is not None:
                    report_actuators(source)
    finally:
        if live_view is not None:
            live_view.close()
        if link is not None:
            link.close()
    extra = {"take": take_path} if take_path else {}
    if desk is not None:
        extra["shot"] = f"{shot_path} ({len(desk.session.keys.keys)} keys)"
    print_summary(summary, False, extra={**extra, **(report_link(link) if link else {})})


COMMANDS = (live,)
