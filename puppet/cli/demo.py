"""``puppet demo``: the built-in character on a simulated bus, into a video."""

from __future__ import annotations

import click

from puppet.cli.common import Null, fail, make_sinks, print_summary, progress


@click.command()
@click.option("--out", default="demo.mp4", show_default=True, help="Video file to write.")
@click.option("--seconds", default=10.0, show_default=True, type=click.FloatRange(min=0.1),
              help="Length of the run.")
@click.option("--faults", default=None, type=click.Path(exists=True, dir_okay=False),
              help="hw_sim fault file to play during the run.")
@click.option("--size", default=(640, 480), type=(int, int), show_default=True, help="Frame size.")
@click.option("--fps", default=30.0, show_default=True, help="Video frame rate.")
@click.option("--antialias", type=click.Choice(["auto", "msaa", "fxaa", "none"]), default="auto",
              show_default=True, help="auto: MSAA on a GPU, none on a software renderer.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def demo(out: str, seconds: float, faults: str | None, size: tuple[int, int], fps: float,
         antialias: str, as_json: bool) -> None:
    """Run the live loop on the built-in character and a simulated bus, into a video.

    \b
    Example:
      puppet demo --seconds 5 --out demo.mp4
    """
    from hw_sim.errors import FaultFileError
    from hw_sim.faults import FaultSchedule

    from puppet.demo import run_demo

    if faults is not None:  # checked before anything starts: a bad file is the user's to fix
        try:
            faults = FaultSchedule.from_file(faults)
        except FaultFileError as err:
            fail(str(err))
    bar, on_frame = progress(seconds, "demo")
    with bar if bar is not None else Null():
        summary, report = run_demo(seconds=seconds, faults=faults, width=size[0], height=size[1],
                                   video_fps=fps, on_frame=on_frame, antialias=antialias,
                                   sinks_for=lambda _p: make_sinks(out, None, fps))
    print_summary(summary, as_json, extra={"video": out, "read_mode": report.read_mode})


COMMANDS = (demo,)
