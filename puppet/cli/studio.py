"""``puppet studio``: a session folder of shots and numbered takes run from one page (record
with a count-in, review, circle, note, lock, trash, segments, export), on a puppet or, with
--demo, the built-in critter on a simulated bus."""

from __future__ import annotations

import click

from puppet import limits
from puppet.cli.common import InRange, fail, rig_files, run_session, say

READ_RATE_HZ = 500.0
"""Bus cycles per second (as ``puppet live``)."""


@click.command()
@click.argument("session_folder", metavar="SESSION")
@click.option("--rig", "rig_path", default=None, help="Rig file (TOML); not with --demo.")
@click.option("--port", default=None, help="Serial port, e.g. /dev/ttyUSB0 or hw-sim's pty.")
@click.option("--demo", is_flag=True,
              help="The built-in critter on a simulated bus (no puppet needed).")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
@click.option("--address", "address", default="", metavar="[HOST:]PORT",
              help="Where to serve the page (default 127.0.0.1:8765; another host gets a URL "
                   "with a token).")
@click.option("--sound", "sound_path", default=None, metavar="FILE",
              help="The shot's sound (WAV, FLAC, OGG, MP3): every take stores its reference "
                   "(hash, offset, rate) from its time 0.")
@click.option("--size", default=(640, 480), show_default=True,
              type=(InRange(limits.FRAME_SIZE), InRange(limits.FRAME_SIZE)),
              help=f"Frame size: width and height, each {limits.FRAME_SIZE}.")
@click.option("--fps", default=30.0, show_default=True, type=InRange(limits.FPS),
              help=f"The shot's frame rate ({limits.FPS}): its takes' timecode rate, and their "
                   "exports' unless told otherwise on the page.")
@click.option("--seconds", default=None, type=InRange(limits.SECONDS),
              help=f"Stop after this long ({limits.SECONDS}; default: Ctrl-C).")
def studio(session_folder: str, rig_path: str | None, port: str | None, demo: bool, baud: int,
           address: str, sound_path: str | None, size: tuple[int, int],
           fps: float, seconds: float | None) -> None:
    """Run a session of shots and takes from one browser page; prints the page's address.

    SESSION is a folder (made if new): takes/<shot>/takeNNN.mcap, session.json (the index),
    trash/, exports/. One studio at a time holds it.

    \b
    Example:
      puppet studio shoot --demo                        the built-in critter, simulated
      puppet studio shoot --rig my.toml --port /dev/ttyUSB0
      puppet batch shoot --circled --formats gltf       the circled takes, from the terminal
    """
    from puppet.rig.load import builtin, load_rig
    from puppet.session import Session
    from puppet.session import outputs as o
    from puppet.session.sources import BusSource, Switchable

    if demo:
        if rig_path is not None or port is not None:
            fail("--demo runs the built-in critter on a simulated bus: no --rig or --port")
        from puppet.demo import demo_source

        rig = builtin()
        bus = demo_source(rig)
    else:
        if rig_path is None or port is None:
            fail("give --rig RIG and --port PORT (or --demo for the built-in critter)")
        rig = load_rig(rig_path)
        bus = BusSource(rig, port, baud=baud, rate_hz=READ_RATE_HZ)
    outputs = [o.Studio(session_folder, address, rig, tell=say)]
    if sound_path is not None:
        outputs.append(o.Sound(sound_path, tell=say, device=False))  # heard on the page
    session = Session(rig, Switchable(bus), outputs, inputs=[*rig_files(rig), sound_path],
                      seconds=seconds, tell=say, video_fps=fps, say_setup=not demo,
                      pipeline={"overlay": True, "width": size[0], "height": size[1],
                                "live": True})
    run_session(session)


COMMANDS = (studio,)
