"""``puppet scan`` and ``puppet calibrate``: commands that talk to a bus directly."""

from __future__ import annotations

from pathlib import Path

import click

from puppet import limits
from puppet.cli.common import InRange, fail, force_option, load_rig, print_setup, rig_files



def _on_port(port: str, err) -> str:
    """A bus error's text naming ``port`` once (a PortError's own text names it)."""
    return str(err) if str(err).startswith(f"port {port}:") else f"port {port}: {err}"


def _ping_all(port: str, baud: int) -> dict:
    """The servos on ``port`` at ``baud``: {id: (model number, firmware)} of one protocol (2.0
    first, then 1.0: a bus carries one; ``puppet.bus.scan``); a bus error is an Error line."""
    from puppet.bus import BusError
    from puppet.bus.scan import scan as scan_bus

    try:
        for protocol in (2.0, 1.0):
            found = scan_bus(port, (baud,), (protocol,))
            if found:
                return {f.id: (f.number, f.firmware) for f in found}
    except BusError as err:
        fail(_on_port(port, err))
    return {}


class BaudOrAll(InRange):
    """``--baud``: a rate in limits.BAUD, or 'all' (every standard rate, ``scan.SCAN_BAUDS``)."""

    def convert(self, value, param, ctx):
        if isinstance(value, str) and value.strip().lower() == "all":
            return "all"
        return super().convert(value, param, ctx)


@click.command()
@click.option("--port", required=True, help="Serial port.")
@click.option("--baud", default="1000000", show_default=True, type=BaudOrAll(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}, or 'all': every standard rate from 9600 to "
                   "4 Mbit/s in turn (about half a minute).")
def scan(port: str, baud) -> None:
    """List the servos on a bus: a Protocol 2.0 broadcast ping and a Protocol 1.0 ping of
    every id, at one baud rate or at each standard one; prints baud, protocol, id, model and
    firmware.

    \b
    Example:
      puppet scan --port /dev/ttyUSB0
      puppet scan --port /dev/ttyUSB0 --baud all
    """
    from puppet.bus import BusError
    from puppet.bus.scan import SCAN_BAUDS, scan as scan_bus

    bauds = SCAN_BAUDS if baud == "all" else (baud,)
    try:
        found = scan_bus(port, bauds, log=lambda line: click.echo(line, err=True))
    except BusError as err:
        fail(_on_port(port, err))
    if not found:
        at = "any standard rate" if baud == "all" else f"{baud} bps"
        fail(f"port {port}: no servo answered a ping at {at} (Protocol 1.0 nor 2.0): check the "
             "power, the cable and the baud rate (--baud all tries each)")
    click.echo(f"{'baud':>8}  protocol  {'id':>3}  {'model':<12} {'number':>6}  firmware")
    for f in found:
        click.echo(f"{f.baud:>8}  {f.protocol:>8.1f}  {f.id:>3}  {f.model or 'unknown':<12} "
                   f"{f.number:>6}  {f.firmware}")


@click.command()
@click.option("--rig", "rig_path", required=True, help="Rig file (TOML).")
@click.option("--port", required=True, help="Serial port.")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
@click.option("--out", default=None, help="Calibration file (default: the one the rig names, else "
              "<rig>.calibration.toml beside it, which the rig then reads); with --guided, "
              "a rig file to write instead of updating RIG.")
@click.option("--guided", is_flag=True, help="Find each [[servo]] block's id, sign and zero ticks by "
              "moving its joint when asked; writes them into the rig file.")
@click.option("--yes", is_flag=True, help="With --guided: do not wait for Enter before reading the "
              "rest pose.")
@click.option("--timeout", "timeout_s", default=120.0, show_default=True,
              type=InRange(limits.TIMEOUT_S),
              help=f"With --guided: seconds to wait for each joint to move and to come back "
                   f"({limits.TIMEOUT_S}).")
@click.option("--threshold", default=limits.THRESHOLD_DEG_DEFAULT, show_default=True,
              type=InRange(limits.THRESHOLD_DEG),
              help=f"With --guided: degrees of joint turn a move must reach to count, the same on "
                   f"every model ({limits.THRESHOLD_DEG}).")
@force_option
def calibrate(rig_path: str, port: str, baud: int, out: str | None, guided: bool = False,
              yes: bool = False, timeout_s: float = 120.0, threshold: float = limits.THRESHOLD_DEG_DEFAULT,
              force: bool = False) -> None:
    """Capture the zero pose: hold the puppet in the rig's rest pose, then run this.

    With --guided, also find which servo each [[servo]] block is and its sign: move each joint
    in its positive direction when asked, then back to rest.

    \b
    Example:
      puppet calibrate --rig my.toml --port /dev/ttyUSB0
      puppet calibrate --rig my.toml --port /dev/ttyUSB0 --guided
    """
    if guided:
        _calibrate_guided(rig_path, port, baud, out, yes, timeout_s, threshold, force)
        return
    from puppet.atomic import check_output
    from puppet.bus import BusError, ServoReader
    from puppet.rig import Calibration

    from puppet.rig.rig_file import default_calibration

    rig = load_rig(rig_path)
    target = out or rig.calibration.path
    if target is None and rig_path is not None and Path(rig_path).suffix.lower() == ".toml":
        target = default_calibration(rig_path)  # the rig reads it from now on
    if target is None:
        fail(f"{rig_path or 'the built-in rig'}: no calibration file to write (the built-in "
             "rig, or a bare character); pass --out FILE")
    # the rig's own calibration file is what this command rewrites; every other file is an input
    own = rig.calibration.path
    inputs = [f for f in rig_files(rig) if own is None or Path(f).resolve() != Path(own).resolve()]
    rule = dict(kind="calibration", inputs=inputs, force=force, what="calibration file")
    check_output(target, **rule)  # before the bus: a refused output costs nothing
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
        fail(_on_port(port, err))
    finally:
        reader.close()
    path = Calibration.capture(reading.ids, reading.ticks).save(target, inputs=inputs, force=force)
    click.echo(f"calibration: {path}")
    for dxl_id, ticks in zip(reading.ids, reading.ticks):
        click.echo(f"  servo {int(dxl_id)}: zero {int(ticks)}")


GUIDED_PING_TRIES = 3
"""``calibrate --guided``: scans of the bus (each with its own passes) until as many servos answer
as the rig has [[servo]] blocks."""


def _calibrate_guided(rig_path: str, port: str, baud: int, out: str | None, yes: bool,
                      timeout_s: float, threshold: float, force: bool) -> None:
    """``calibrate --guided``: prompts on stderr, results written into the rig file."""
    from puppet.bus import BusError, ServoReader
    from puppet.servo_models import MODELS_BY_NUMBER
    from puppet.rig.guided_calibration import GuidedCalibration

    session = GuidedCalibration(rig_path)
    session.check_out(out, force=force)  # before the bus: a refused output costs nothing
    found = _ping_all(port, baud)
    for _ in range(GUIDED_PING_TRIES - 1):  # a busy host misses replies (Protocol 1.0: 4 ms each)
        if len(found) >= len(session.steps):
            break
        click.echo(f"{len(found)} of the rig's {len(session.steps)} servos answered; pinging again",
                   err=True)
        found = {**found, **_ping_all(port, baud)}
    unknown = sorted(i for i, (number, _) in found.items() if number not in MODELS_BY_NUMBER)
    if unknown:
        click.echo(f"warning: servos {unknown} are of a model puppet cannot read; left out", err=True)
    models = {i: MODELS_BY_NUMBER[number].name for i, (number, _) in sorted(found.items())
              if number in MODELS_BY_NUMBER}
    if not models:
        fail(f"port {port}: no servo answered a broadcast ping at {baud} bps")
    click.echo(f"servos on {port}: " + ", ".join(f"{i} ({m})" for i, m in models.items()), err=True)
    if not yes:
        click.prompt("Hold the puppet in the rig's rest pose and press Enter", default="",
                     show_default=False, err=True, prompt_suffix=" ")
    reader = ServoReader(port, models, baud=baud)
    try:
        print_setup(reader.open(), port)
        rest = reader.read_clean(samples=9, timeout_s=5.0)
        click.echo("rest pose read: " + ", ".join(f"{int(i)}={int(t)}" for i, t in zip(rest.ids, rest.ticks)),
                   err=True)
        results = session.run(reader.read, rest, say=lambda text: click.echo(text, err=True), models=models,
                              threshold_deg=threshold, timeout_s=timeout_s)
    except BusError as err:
        fail(_on_port(port, err))
    finally:
        reader.close()
    path = session.write(results, out, force=force)
    click.echo(f"rig file: {path}")
    if session.calibration_file is not None:
        click.echo(f"calibration: {session.calibration_file} (zero ticks updated too)")
    for f in results:
        click.echo(f"  {f.step.joint} ({f.step.axis_text}): servo {f.id}, sign {f.sign:+d}, zero {f.zero_ticks}")


COMMANDS = (scan, calibrate)
