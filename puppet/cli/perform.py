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
@click.option("--sound", "sound_path", default=None, metavar="FILE",
              help="Play this sound with the motors (default: the take's own, found by its hash); "
                   "on this machine's sound device, from the take's time 0.")
@click.option("--silent", is_flag=True, help="Perform without the take's sound.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as one JSON line.")
def perform(take: str, rig_path: str | None, port: str, baud: int, speed: float, loop: bool,
            yes: bool, no_watchdog: bool, watchdog_ms: float, rate_hz: float,
            latency_ms: int | None, sound_path: str | None, silent: bool, as_json: bool) -> None:
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

    player = None if silent else _player(reader, sound_path, speed, loop, log)

    def on_phase(phase: str) -> None:
        click.echo(f"phase: {phase}", err=True)
        if player is not None and phase == "playback":
            player.start(player.clock())  # sample offset_s is heard at the motors' take time 0
        elif player is not None and phase == "stop":
            player.stop()  # with the motors' last goal, before torque goes off

    try:
        report = run(rig, reader, port, options, log=log, on_phase=on_phase)
    except DriveError as err:
        if err.report is not None:
            click.echo(err.report.text(), err=True)
        raise
    finally:
        if player is not None:
            player.stop()
    if as_json:
        click.echo(json.dumps(report.as_dict()))
    else:
        click.echo(report.text())


def _player(reader, sound_path: str | None, speed: float, loop: bool, log):
    """The take's sound (or --sound FILE) on the sound device, pre-rolled now (its stream runs
    silent until the playback starts); None without a sound, a device, or at a --speed other
    than 1 (said once)."""
    from puppet.sound import sound_for_take
    from puppet.sound.device import DevicePlayer

    if sound_path is None and reader.metadata.sound is None:
        return None
    if speed != 1.0:
        log(f"warning: --speed {speed:g}: the performance is silent (its sound plays at speed 1 only)")
        return None
    sound, offset_s, warning = sound_for_take(reader, sound_path)
    if warning is not None:
        log(f"warning: {warning}")
    if sound is None:
        return None
    if loop:
        log("note: --loop: the sound plays with the first pass only")
    player = DevicePlayer(sound, offset_s)
    if not player.prepare():
        log(player.message)
        return None
    return player


COMMANDS = (perform,)
