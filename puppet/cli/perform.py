"""``puppet perform``: play a take on the puppet's servos (torque on; off on every way out)."""

from __future__ import annotations

import json

import click

from puppet import limits
from puppet.cli.common import InRange, load_rig


@click.command()
@click.argument("take")
@click.option("--rig", "rig_path", default=None, help="Rig file of the puppet (default: built-in).")
@click.option("--port", required=True, help="Serial port of the bus.")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
@click.option("--speed", default=1.0, show_default=True, type=InRange(limits.SPEED),
              help=f"Playback speed factor ({limits.SPEED}).")
@click.option("--loop", is_flag=True, help="Repeat the take until stopped.")
@click.option("--yes", is_flag=True, help="No countdown before the move to the first pose; "
              "and perform a replay longer than 10 min (refused without it).")
@click.option("--no-watchdog", is_flag=True,
              help="Perform on servos without the Bus Watchdog, by model or firmware (a host crash "
                   "leaves them driving).")
@click.option("--watchdog-ms", default=100.0, show_default=True, type=InRange(limits.WATCHDOG_MS),
              help=f"Bus Watchdog period ({limits.WATCHDOG_MS}; at least three loop periods).")
@click.option("--rate", "rate_hz", default=100.0, show_default=True,
              type=InRange(limits.GOAL_RATE_HZ),
              help=f"Goal writes per second ({limits.GOAL_RATE_HZ}).")
@click.option("--latency-ms", default=None, type=InRange(limits.LATENCY_MS),
              help=f"Adapter latency the SDK timeouts assume ({limits.LATENCY_MS}; default: the "
                   "adapter's, or 1).")
@click.option("--json", "as_json", is_flag=True, help="Print the report as one JSON line.")
def perform(take: str, rig_path: str | None, port: str, baud: int, speed: float, loop: bool,
            yes: bool, no_watchdog: bool, watchdog_ms: float, rate_hz: float,
            latency_ms: int | None, as_json: bool) -> None:
    """Perform a take on the puppet's servos.

    Goals come from the take's joint angles through this rig's calibration, clamped to its
    limits and rate-limited. Torque goes on with goal = present, then a slow move to the first
    pose after a countdown; on any stop torque goes off and is read back.

    \b
    Example:
      puppet perform take.mcap --rig my.toml --port /dev/ttyUSB0 --speed 0.5
    """
    from puppet.drive import DriveError, PerformOptions
    from puppet.drive import perform as run
    from puppet.take import TakeReader

    rig = load_rig(rig_path)
    reader = TakeReader(take)  # what it skipped or cut is said by perform, before torque on
    options = PerformOptions(speed=speed, loop=loop, yes=yes, watchdog=not no_watchdog,
                             watchdog_ms=watchdog_ms, rate_hz=rate_hz, baud=baud,
                             latency_ms=latency_ms)

    def log(line: str) -> None:
        click.echo(line, err=True)

    try:
        report = run(rig, reader, port, options, log=log,
                     on_phase=lambda p: click.echo(f"phase: {p}", err=True))
    except DriveError as err:
        if err.report is not None:
            click.echo(err.report.text(), err=True)
        raise
    if as_json:
        click.echo(json.dumps(report.as_dict()))
    else:
        click.echo(report.text())


COMMANDS = (perform,)
