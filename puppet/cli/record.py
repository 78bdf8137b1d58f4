"""``puppet record``: raw servo readings into a take, without solving or rendering."""

from __future__ import annotations

import time

import click

from puppet import limits
from puppet.cli.common import (InRange, StopFlag, check_take_path, load_rig, start_reader,
                               take_writer)


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
def record(rig_path: str, port: str, out: str, baud: int, seconds: float | None, rate: float,
           force: bool) -> None:
    """Record a take (raw servo readings) without solving or rendering: the lightest loop.

    \b
    Example:
      puppet record --rig my.toml --port /dev/ttyUSB0 --out take.mcap --seconds 30
    """
    rig = load_rig(rig_path)
    check_take_path(out, rig, force=force)  # before the port: a mistake costs no take
    source = start_reader(rig, port, baud, rate_hz=rate)
    try:
        writer = take_writer(out, rig, force=force)  # the file is made once the port answers
        stop = StopFlag()
        start = time.monotonic()
        count = flagged = 0
        try:
            while not stop() and (seconds is None or time.monotonic() - start < seconds):
                batch = source.drain()
                if not batch:
                    time.sleep(0.005)
                for reading in batch:
                    writer.write(reading)
                    count += 1
                    flagged += int(not reading.ok.all())
        finally:
            writer.close()
    finally:
        source.stop()
    click.echo(f"take: {out}\nreadings: {count} in {time.monotonic() - start:.2f} s, "
               f"{flagged} with a flagged servo\nfaults seen: {dict(source.log.counts) or 'none'}")


COMMANDS = (record,)
