"""``puppet scan`` and ``puppet calibrate``: commands that talk to a bus directly."""

from __future__ import annotations

import click

from puppet.cli.common import fail, load_rig, print_setup


@click.command()
@click.option("--port", required=True, help="Serial port.")
@click.option("--baud", default=1_000_000, show_default=True, help="Bus baud rate.")
def scan(port: str, baud: int) -> None:
    """List the servos on a bus (broadcast ping): ids, models, firmware.

    \b
    Example:
      puppet scan --port /dev/ttyUSB0
    """
    from puppet.bus import BusError, BusLink
    from puppet.bus.control_table import MODELS_BY_NUMBER

    link = BusLink(port, baud=baud)
    try:
        link.open()
        found = link.broadcast_ping()
    except BusError as err:
        fail(f"port {port}: {err}")
    finally:
        link.close()
    if not found:
        fail(f"port {port}: no servo answered a broadcast ping at {baud} bps")
    click.echo(f"{'id':>4}  {'model':<12} {'number':>6}  firmware")
    for dxl_id, (number, firmware) in sorted(found.items()):
        model = MODELS_BY_NUMBER.get(number)
        click.echo(f"{dxl_id:>4}  {model.name if model else 'unknown':<12} {number:>6}  {firmware}")


@click.command()
@click.option("--rig", "rig_path", required=True, help="Rig file (TOML).")
@click.option("--port", required=True, help="Serial port.")
@click.option("--baud", default=1_000_000, show_default=True, help="Bus baud rate.")
@click.option("--out", default=None, help="Calibration file (default: the rig's).")
def calibrate(rig_path: str, port: str, baud: int, out: str | None) -> None:
    """Capture the zero pose: hold the puppet in the rig's rest pose, then run this.

    \b
    Example:
      puppet calibrate --rig my.toml --port /dev/ttyUSB0
    """
    from puppet.bus import BusError, ServoReader
    from puppet.rig import Calibration

    rig = load_rig(rig_path)
    target = out or rig.calibration.path
    if target is None:
        fail(f"{rig_path}: the rig names no calibration file; pass --out FILE")
    reader = ServoReader(port, rig.servo_map.models, baud=baud)
    try:
        report = reader.open()
        if report.missing:
            names = ", ".join(f"{i} ({rig.servo_map.models[i]})" for i in report.missing)
            fail(f"port {port}: servo{'s' if len(report.missing) > 1 else ''} {names} of {rig_path} "
                 "did not answer: check its power, cable and id; nothing was written")
        print_setup(report, port)
        # generous: a loaded machine may hold replies; a servo that never reads is named
        reading = reader.read_clean(samples=9, timeout_s=15.0)
    except BusError as err:
        fail(f"port {port}: {err}")
    finally:
        reader.close()
    path = Calibration.capture(reading.ids, reading.ticks).save(target)
    click.echo(f"calibration: {path}")
    for dxl_id, ticks in zip(reading.ids, reading.ticks):
        click.echo(f"  servo {int(dxl_id)}: zero {int(ticks)}")


COMMANDS = (scan, calibrate)
