"""``puppet record``: raw servo readings into a take, without solving or rendering."""

from __future__ import annotations

import click

from puppet import limits
from puppet.cli.common import InRange, load_rig, rig_files, say, sound_options, sound_outputs


@click.command()
@click.option("--rig", "rig_path", required=True, help="Rig file (TOML).")
@click.option("--port", required=True, help="Serial port.")
@click.option("--out", required=True, help="Take file to write (.mcap).")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
@click.option("--seconds", default=None, type=InRange(limits.SECONDS),
              help=f"Stop after this long ({limits.SECONDS}; default: Ctrl-C).")
@click.option("--rate", default=500.0, show_default=True, type=InRange(limits.READ_RATE_HZ),
              help=f"Readings per second ({limits.READ_RATE_HZ}).")
@click.option("--force", is_flag=True, help="Replace an existing take file.")
@sound_options
def record(rig_path: str, port: str, out: str, baud: int, seconds: float | None, rate: float,
           force: bool, sound_path: str | None, sound_offset: float, count_in: float) -> None:
    """Record a take (raw servo readings) without solving or rendering: the lightest loop.

    \b
    Example:
      puppet record --rig my.toml --port /dev/ttyUSB0 --out take.mcap --seconds 30
    """
    from puppet.events import HELD_READING, describe_counts
    from puppet.session import Session
    from puppet.session import outputs as o
    from puppet.session.sources import BusSource

    rig = load_rig(rig_path)
    take = o.Take(out, rig, force=force, option="--out")  # checked before the port: a mistake costs no take
    session = Session(rig, BusSource(rig, port, baud=baud, rate_hz=rate),
                      [take, *sound_outputs(sound_path, sound_offset, count_in)],
                      inputs=[*rig_files(rig), sound_path], seconds=seconds, solve=False,
                      latch_fps=None, tell=say, count_in_s=count_in)
    summary = session.run()
    written = take.readings > 0  # the take file is made with its first reading
    if session.stopped_by is not None:
        say(f"stopped by {session.stopped_by}; " + ("the take holds every reading until then"
                                                    if written else "before the first reading"))
    held = summary.faults.pop(HELD_READING, 0)
    click.echo(f"take: {take.report()['take']}\n"  # the output's own words: no file, said
               f"readings: {take.readings} in {summary.seconds:.2f} s, "
               f"{held} {HELD_READING}\nfaults seen: {describe_counts(summary.faults)}")


COMMANDS = (record,)
