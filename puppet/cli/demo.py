"""``puppet demo``: the built-in character on a simulated bus, into a video."""

from __future__ import annotations

import click

from puppet import limits
from puppet.cli.common import (InRange, Null, StopFlag, fail, force_option, make_sinks,
                               print_summary, progress, rig_files)
from puppet.cli.blender import link_option, open_link, report_link
from puppet.cli.view import open_view, take_factory_for, view_option


@click.command()
@click.option("--out", default="demo.mp4", show_default=True, help="Video file to write.")
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

    from puppet.atomic import check_output
    from puppet.demo import run_demo
    from puppet.rig.load import BUILTIN_AX_RIG, BUILTIN_DYNAMICS_RIG, builtin, load_rig

    fault_file = faults
    if faults is not None:  # checked before anything starts: a bad file is the user's to fix
        try:
            faults = FaultSchedule.from_file(faults)
        except FaultFileError as err:
            fail(str(err))
    if dynamics and ax:
        fail("--dynamics and --ax are two variants of the critter: choose one")
    rig = load_rig(BUILTIN_DYNAMICS_RIG) if dynamics else load_rig(BUILTIN_AX_RIG) if ax else builtin()
    inputs = [fault_file, *rig_files(rig)]
    check_output(out, kind="video", inputs=inputs, force=force, what="video")  # opened later
    live_view = link = None
    if link_address is not None:  # bound before the simulated bus starts
        link = open_link(link_address, rig)
    if view_address is not None:  # bound before the simulated bus starts
        live_view = open_view(view_address, mode="live", take_factory=take_factory_for(rig))
    elif seconds is None and link is None:
        seconds = 10.0
    bar, on_frame = progress(seconds, "demo")
    try:
        with bar if bar is not None else Null():
            summary, report = run_demo(seconds=seconds, faults=faults, width=size[0], height=size[1],
                                       video_fps=fps, on_frame=on_frame, antialias=antialias,
                                       sinks_for=lambda _p: make_sinks(out, None, fps, inputs=inputs,
                                                                      force=force),
                                       view=live_view, should_stop=StopFlag(), rig=rig,
                                       link=link)
    finally:
        if live_view is not None:
            live_view.close()
        if link is not None:
            link.close()
    print_summary(summary, as_json, extra={"video": out, "read_mode": report.read_mode,
                                           "dynamics": rig.extras.dynamics is not None,
                                           **(report_link(link) if link is not None else {})})


COMMANDS = (demo,)
