"""``puppet release``: torque off on every servo of a bus and their Bus Watchdog cleared."""

from __future__ import annotations

import click

from puppet import limits
from puppet.cli.common import InRange, fail, load_rig


@click.command()
@click.option("--port", required=True, help="Serial port of the bus.")
@click.option("--rig", "rig_path", default=None,
              help="Release this rig's servos too, even those that do not answer a ping (every "
                   "servo that answers is released, named when not in the rig).")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
def release(port: str, rig_path: str | None, baud: int) -> None:
    """Turn torque off on every servo and clear its Bus Watchdog, read back.

    For servos a program left with torque on (an adapter pulled during perform, a crash).

    \b
    Example:
      puppet release --port /dev/ttyUSB0
    """
    from puppet.drive.release import release as run

    models = None if rig_path is None else dict(load_rig(rig_path).servo_map.models)
    done = run(port, models, baud=baud, log=lambda line: click.echo(line, err=True))
    for dxl_id, torque in done.torque.items():
        watchdog = (f"Bus Watchdog {_value(done.watchdog[dxl_id])}" if dxl_id in done.watchdog
                    else "no Bus Watchdog")
        click.echo(f"servo {dxl_id}: Torque Enable {_value(torque)}, {watchdog} (read back)")
    on = {i: v for i, v in done.torque.items() if v != 0}
    if on:
        fail(f"port {port}: servo{'s' if len(on) > 1 else ''} {sorted(on)}: torque not confirmed "
             f"off (read back {on})")
    if done.missing:
        fail(f"port {port}: servo{'s' if len(done.missing) > 1 else ''} {done.missing} of "
             f"{rig_path} did not answer: torque unknown")


def _value(value) -> str:
    return "unreadable" if value is None else str(value)


COMMANDS = (release,)
