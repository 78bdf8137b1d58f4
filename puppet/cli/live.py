"""``puppet live``: read the puppet, solve and render until Ctrl-C (optionally recording)."""

from __future__ import annotations

from pathlib import Path

import click

from puppet import limits
from puppet.cli.blender import link_option
from puppet.cli.common import (InRange, load_rig, rig_files, run_session, say,
                               sound_options, sound_outputs)
from puppet.cli.view import view_option

READ_RATE_HZ = 500.0
"""Bus cycles per second in live (a read of every servo, and the actuators' goal write)."""


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
@sound_options
@click.option("--over", "base_path", default=None,
              help="Record a layer over this take (its base): the base plays from the layer's "
                   "time 0 (after --count-in, holding its first frame until then), "
                   "driven on the puppet where its servos can drive, on screen otherwise; name "
                   "the layer's joints with --joints or --servos.")
@click.option("--joints", default=None, help="With --over: the layer's joints, e.g. head,neck.")
@click.option("--servos", "servo_ids", default=None,
              help="With --over: the layer's servo ids, e.g. 3,4.")
@view_option
@link_option
def live(rig_path: str, port: str, baud: int, take_path: str | None, out: str | None,
         frames: str | None, seconds: float | None, fps: float, antialias: str,
         force: bool, shot_path: str | None, view_address: str | None,
         link_address: str | None, watchdog_ms: float, no_watchdog: bool,
         sound_path: str | None, sound_offset: float, count_in: float,
         base_path: str | None, joints: str | None, servo_ids: str | None) -> None:
    """Read the puppet, solve and render live until Ctrl-C.

    Servos with role = "actuator" in the rig file are driven to the angle the solve gives
    their joint (torque on while live runs, off on every way out).

    \b
    Example:
      puppet live --rig my.toml --port /dev/ttyUSB0 --record take.mcap --out live.mp4
      puppet live --rig my.toml --port /dev/ttyUSB0 --view     watch at the printed URL
      puppet live --rig my.toml --port /dev/ttyUSB0 --view --keys shot.mcap   key poses from the page
      puppet live --rig my.toml --port /dev/ttyUSB0 --link     into Blender (puppet_link add-on)
      puppet live --rig my.toml --port /dev/ttyUSB0 --over body.mcap --joints head,neck \\
          --record head.mcap                                  a layer over a take
    """
    from puppet.session import Session
    from puppet.session import outputs as o
    from puppet.session.sources import BusSource

    rig = load_rig(rig_path)
    if shot_path is not None and view_address is None:
        raise click.UsageError("--keys takes keys from the page: add --view (or use `puppet keys`)")
    watchdog = 0.0 if no_watchdog else watchdog_ms
    if base_path is None:
        if joints is not None or servo_ids is not None:
            raise click.UsageError("--joints and --servos name a layer's joints: add --over BASE")
        source = BusSource(rig, port, baud=baud, rate_hz=READ_RATE_HZ)
        outputs = [o.Actuators(rig, READ_RATE_HZ, watchdog_ms=watchdog, tell=say)]
        if take_path is not None:
            outputs.append(o.Take(take_path, rig, force=force))
    else:
        from puppet.session.layers import layer_parts

        _, source, outputs = layer_parts(rig, port, base_path, take_path, joints=_names(joints),
                                         servos=_ids(servo_ids), baud=baud, rate_hz=READ_RATE_HZ,
                                         watchdog_ms=watchdog, force=force, tell=say)
    if out is not None:
        outputs.append(o.Video(out, fps, force=force))
    if frames is not None:
        outputs.append(o.Frames(frames))
    desk = None
    if shot_path is not None:
        from puppet.cli.keys import new_desk

        desk = new_desk(rig, shot_path)
        outputs.append(o.KeyDesk(desk, path=shot_path, rig=rig, feed=False, force=force))
    if link_address is not None:
        outputs.append(o.Link(link_address, rig, tell=say))
    if view_address is not None:
        outputs.append(o.View(view_address, mode="live", rig=rig, record=True, keys=desk,
                              takes_dir=Path(take_path).parent if take_path else Path("."),
                              tell=say))
    outputs += sound_outputs(sound_path, sound_offset, count_in)
    session = Session(rig, source, outputs, inputs=[*rig_files(rig), base_path, sound_path],
                      seconds=seconds, video_fps=fps, tell=say, count_in_s=count_in, solve=True,
                      pipeline={"overlay": True, "antialias": antialias, "live": True})
    run_session(session)


def _names(text: str | None) -> list[str]:
    return [] if not text else [t.strip() for t in text.split(",") if t.strip()]


def _ids(text: str | None) -> list[int]:
    try:
        return [int(t) for t in _names(text)]
    except ValueError:
        raise click.BadParameter(f"{text!r}: servo ids, e.g. 3,4", param_hint="--servos") from None


COMMANDS = (live,)
