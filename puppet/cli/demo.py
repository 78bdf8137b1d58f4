"""``puppet demo``: the built-in character on a simulated bus, into a video."""

from __future__ import annotations

import click

from puppet import limits
from puppet.cli.common import (InRange, Null, fail, force_option, progress, rig_files,
                               run_session, say)
from puppet.cli.blender import link_option
from puppet.cli.view import view_option


@click.command()
@click.option("--out", default=None,
              help="Video file to write [default: demo.mp4; with --link none unless given].")
@click.option("--seconds", default=None, type=InRange(limits.SECONDS),
              help=f"Length of the run ({limits.SECONDS}) [default: 10; with --view: until "
                   "Ctrl-C].")
@click.option("--faults", default=None, type=click.Path(exists=True, dir_okay=False),
              help="hw_sim fault file to play during the run.")
@click.option("--size", default=(640, 480), show_default=True,
              type=(InRange(limits.FRAME_SIZE), InRange(limits.FRAME_SIZE)),
              help=f"Frame size: width and height, each {limits.FRAME_SIZE}.")
@click.option("--fps", default=30.0, show_default=True, type=InRange(limits.FPS),
              help=f"Frame rate of the video and frames ({limits.FPS}).")
@click.option("--antialias", type=click.Choice(["auto", "msaa", "fxaa", "none"]), default="auto",
              show_default=True, help="auto: MSAA on a GPU, FXAA on a software renderer.")
@click.option("--dynamics", is_flag=True,
              help="Secondary motion on: the ears and tail lag and settle (the built-in "
                   "critter_dynamics.toml).")
@click.option("--ax", is_flag=True,
              help="The critter on Protocol 1.0 servos: AX-12A and MX-28 on the simulated bus "
                   "(the built-in critter_ax.toml).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@view_option
@link_option
@force_option
def demo(out: str, seconds: float | None, faults: str | None, size: tuple[int, int], fps: float,
         antialias: str, dynamics: bool, ax: bool, as_json: bool, view_address: str | None,
         link_address: str | None, force: bool) -> None:
    """Run the live loop on the built-in character and a simulated bus, into a video.

    \b
    Example:
      puppet demo --seconds 5 --out demo.mp4
      puppet demo --view                 watch it at http://127.0.0.1:8765/ (Ctrl-C stops)
      puppet demo --dynamics             ears and tail lag and settle
      puppet demo --ax                   on AX-12A and MX-28 servos (Protocol 1.0)
      puppet demo --link                 into Blender (the puppet_link add-on)
    """
    from hw_sim.errors import FaultFileError
    from hw_sim.faults import FaultSchedule

    from puppet.demo import demo_source
    from puppet.rig.load import BUILTIN_AX_RIG, BUILTIN_DYNAMICS_RIG, builtin, load_rig
    from puppet.session import Session
    from puppet.session import outputs as o

    fault_file = faults
    if faults is not None:  # checked before anything starts: a bad file is the user's to fix
        try:
            faults = FaultSchedule.from_file(faults)
        except FaultFileError as err:
            fail(str(err))
    if dynamics and ax:
        fail("--dynamics and --ax are two variants of the critter: choose one")
    rig = load_rig(BUILTIN_DYNAMICS_RIG) if dynamics else load_rig(BUILTIN_AX_RIG) if ax else builtin()
    if out is None and link_address is None:
        out = "demo.mp4"
    outputs = []
    if out is not None:
        outputs.append(o.Video(out, fps, force=force))
    if link_address is not None:
        outputs.append(o.Link(link_address, rig, tell=say))
    if view_address is not None:
        outputs.append(o.View(view_address, mode="live", rig=rig, record=True, tell=say))
    elif seconds is None and link_address is None:
        seconds = 10.0
    bar, on_frame = progress(seconds, "demo")
    session = Session(rig, demo_source(rig, faults=faults), outputs,
                      inputs=[fault_file, *rig_files(rig)], seconds=seconds, video_fps=fps,
                      on_frame=on_frame, tell=say, say_setup=False,
                      pipeline={"width": size[0], "height": size[1], "antialias": antialias,
                                "overlay": True, "live": True})
    with bar if bar is not None else Null():
        run_session(session, as_json=as_json, extra=lambda run: {
            "read_mode": run.setup.read_mode if run.setup else None,
            "dynamics": rig.extras.dynamics is not None})


COMMANDS = (demo,)
