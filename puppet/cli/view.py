"""``puppet view``: the rig alone in the browser, posed only by dragged point handles (no bus);
and the ``--view`` option the live, demo and play commands share."""

from __future__ import annotations

import click

from puppet import limits
from puppet.cli.common import InRange, load_rig, run_session, say

view_option = click.option(
    "--view", "view_address", is_flag=False, flag_value="", default=None, metavar="[HOST:]PORT",
    help="Watch live in a browser (default 127.0.0.1:8765; another host gets a URL with a token); "
         "prints the URL.")


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
    from puppet.session import Session
    from puppet.session import outputs as o
    from puppet.session.sources import RestPose

    rig = load_rig(rig_path)
    page = o.View(address, mode="rig", tell=say)
    session = Session(rig, RestPose(rig), [page], seconds=seconds, tell=say,
                      pipeline={"overlay": True, "width": size[0], "height": size[1], "live": True})
    run_session(session, extra=lambda _run: {"handles": page.handles})


COMMANDS = (view,)
