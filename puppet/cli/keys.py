"""``puppet keys``: capture key poses from the puppet into a shot, and retime or delete keys."""

from __future__ import annotations

import queue
import sys
import threading
import time

import click

from puppet import limits
from puppet.cli.common import InRange, StopFlag, check_take_path, load_rig, start_reader


WINDOW_WAIT_NS = 10_000_000_000
"""Longest wait for a reading after the hold window (a stalled reader), ns; then the key is
taken from the readings there are (or refused when there are none)."""


def _lines(out: queue.Queue) -> None:
    """Put each stdin line (without its newline) into ``out``, then None at end of input."""
    for line in sys.stdin:
        out.put(line.rstrip("\r\n"))
    out.put(None)


@click.group(invoke_without_command=True)
@click.option("--rig", "rig_path", default=None, help="Rig file (TOML).")
@click.option("--port", default=None, help="Serial port.")
@click.option("--out", default=None, help="Shot file to write (.mcap).")
@click.option("--fps", default=24.0, show_default=True, type=InRange(limits.FPS),
              help=f"The shot's frames per second ({limits.FPS}).")
@click.option("--step", default=12, show_default=True, type=click.IntRange(1, 100_000),
              help="Frames from a key to the next.")
@click.option("--interpolation", default="linear", show_default=True,
              type=click.Choice(["linear", "smooth", "step"]),
              help="How in-betweens fill the frames after each key.")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
@click.option("--force", is_flag=True, help="Replace an existing shot file.")
@click.pass_context
def keys(ctx, rig_path, port, out, fps, step, interpolation, baud, force) -> None:
    """Pose to pose: hold a pose and press Enter; each key lands --step frames after the last.

    \b
    The key is the median of the readings over the 0.2 s after Enter (keep holding).
    Commands (a line each): Enter = new key, `r N` = replace key N with the held pose,
    `d N` = delete key N, `i F` = insert a key at frame F, `q` (or Ctrl-C, end of input) = done.
    The shot is a take with its keys: play, export and batch take it like any take.
    \b
    Examples:
      puppet keys --rig my.toml --port /dev/ttyUSB0 --out shot.mcap --fps 24 --step 12
      puppet keys retime shot.mcap 3=40 4=52 --out retimed.mcap
      puppet keys delete shot.mcap 2 --out fewer.mcap
      puppet keys interpolation shot.mcap 0=smooth 2=step --out smooth.mcap
      puppet keys goto shot.mcap 3 --rig my.toml --port /dev/ttyUSB0   (motorised puppets)
    """
    if ctx.invoked_subcommand is not None:
        return
    from puppet.cli.common import take_header
    from puppet.keys.capture import HOLD_NS, KeyRefused, KeySession
    from puppet.take import TakeError

    missing = [name for name, value in (("--rig", rig_path), ("--port", port), ("--out", out))
               if value is None]
    if missing:
        raise click.UsageError(f"missing {', '.join(missing)} (or a command: retime, delete, interpolation, goto)")
    rig = load_rig(rig_path)
    check_take_path(out, rig, force=force)  # before the port: a mistake costs nothing
    session = KeySession(out, take_header(rig), fps=fps, step=step, interpolation=interpolation)
    source = start_reader(rig, port, baud, rate_hz=200.0)
    commands: queue.Queue = queue.Queue()
    threading.Thread(target=_lines, args=(commands,), daemon=True).start()
    stop = StopFlag()
    click.echo("hold a pose and press Enter for a key (r N, d N, i FRAME, q: see --help)")
    pending = None  # (command, press_ns) waiting for its hold window to end
    try:
        while not stop():
            session.readings.extend(source.drain())
            if pending is None:
                try:
                    line = commands.get(timeout=0.01)
                except queue.Empty:
                    continue
                if line is None or line.strip() == "q":
                    break
                pending = (line, time.monotonic_ns())
                if not session.needs_pose(line):
                    pending = (line, None)
            command, press_ns = pending
            latest = session.readings[-1].t_ns if session.readings else 0
            if press_ns is not None and latest <= press_ns + HOLD_NS:
                if time.monotonic_ns() - press_ns < WINDOW_WAIT_NS:
                    time.sleep(0.005)
                    continue  # the hold window is not over
            pending = None
            try:
                click.echo(session.apply(command, press_ns))
            except (KeyRefused, TakeError) as err:
                click.echo(f"refused: {err}", err=True)
    finally:
        source.stop()
    frames = session.keys.keys[-1].frame if session.keys.keys else 0
    click.echo(f"shot: {out}\nkeys: {len(session.keys.keys)}, {frames} frames at {fps:g} fps\n"
               f"faults seen: {dict(source.log.counts) or 'none'}")


def _edit(shot: str, out: str, force: bool, change) -> None:
    """Read ``shot``, apply ``change(keys) -> keys``, write the result to ``out`` (the output
    rule: never the input, an existing file only with --force)."""
    from puppet.atomic import check_output
    from puppet.keys import read_shot, write_shot

    header, keys, reader = read_shot(shot)
    if reader.recovery is not None:
        click.echo(f"warning: {shot}: {reader.recovery}", err=True)
    target = check_output(out, kind="take", inputs=[shot], force=force, keep_existing=True,
                          what="shot")
    new = change(keys)
    write_shot(target, header, new)
    click.echo(f"shot: {out}\nkeys: " + ", ".join(f"{i}@{k.frame} {k.interpolation}"
                                                 for i, k in enumerate(new.keys)))


@keys.command()
@click.argument("shot")
@click.argument("moves", nargs=-1, required=True)
@click.option("--out", required=True, help="The retimed shot (.mcap; not the input).")
@click.option("--force", is_flag=True, help="Replace an existing file at --out.")
def retime(shot: str, moves: tuple[str, ...], out: str, force: bool) -> None:
    """Move keys to new frames: INDEX=FRAME ... (refused if keys would reorder or share a frame).

    \b
    Example:
      puppet keys retime shot.mcap 3=40 4=52 --out retimed.mcap
    """
    from puppet.keys import retime as retime_keys

    frames = {}
    for index, frame in _pairs(moves, "FRAME", "3=40").items():
        if not frame.isdigit():
            raise click.BadParameter(f"{index}={frame}: FRAME is a whole number, e.g. 3=40")
        frames[index] = int(frame)
    _edit(shot, out, force, lambda k: retime_keys(k, frames, shot))


def _pairs(items: tuple[str, ...], right: str, example: str) -> dict[int, str]:
    """{index: value} of INDEX=VALUE arguments; BadParameter naming a malformed one."""
    pairs = {}
    for item in items:
        index, _, value = item.partition("=")
        if not index.strip().isdigit() or not value.strip():
            raise click.BadParameter(f"{item!r}: expected INDEX={right}, e.g. {example}")
        pairs[int(index)] = value.strip()
    return pairs


@keys.command()
@click.argument("shot")
@click.argument("kinds", nargs=-1, required=True)
@click.option("--out", required=True, help="The shot with new interpolations (.mcap; not the input).")
@click.option("--force", is_flag=True, help="Replace an existing file at --out.")
def interpolation(shot: str, kinds: tuple[str, ...], out: str, force: bool) -> None:
    """How the frames after a key are filled: INDEX=linear|smooth|step ...

    \b
    linear: slerp of each joint's rotation; smooth: a spline in rotation space through the
    keys; step: hold the key until the next.
    Example:
      puppet keys interpolation shot.mcap 0=smooth 2=step --out smooth.mcap
    """
    from puppet.keys import interpolate

    chosen = _pairs(kinds, "KIND", "2=smooth")
    _edit(shot, out, force, lambda k: interpolate(k, chosen, shot))


@keys.command()
@click.argument("shot")
@click.argument("index", type=click.IntRange(0, None))
@click.option("--out", required=True, help="The shot without that key (.mcap; not the input).")
@click.option("--force", is_flag=True, help="Replace an existing file at --out.")
def delete(shot: str, index: int, out: str, force: bool) -> None:
    """Delete key INDEX (the others keep their frames).

    \b
    Example:
      puppet keys delete shot.mcap 2 --out fewer.mcap
    """
    from puppet.keys import remove_key

    _edit(shot, out, force, lambda k: remove_key(k, index, shot))


@keys.command()
@click.argument("shot")
@click.argument("index", type=click.IntRange(0, None))
@click.option("--rig", "rig_path", default=None, help="Rig file of the puppet (default: built-in).")
@click.option("--port", required=True, help="Serial port of the bus.")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
@click.option("--yes", is_flag=True, help="No countdown before the move.")
@click.option("--no-watchdog", is_flag=True,
              help="Move servos without the Bus Watchdog (a host crash leaves them driving).")
@click.option("--watchdog-ms", default=100.0, show_default=True, type=InRange(limits.WATCHDOG_MS),
              help=f"Bus Watchdog period ({limits.WATCHDOG_MS}).")
@click.option("--latency-ms", default=None, type=InRange(limits.LATENCY_MS),
              help=f"Adapter latency the SDK timeouts assume ({limits.LATENCY_MS}).")
def goto(shot: str, index: int, rig_path: str | None, port: str, baud: int, yes: bool,
         no_watchdog: bool, watchdog_ms: float, latency_ms: int | None) -> None:
    """Motorised puppets: ease the servos to key INDEX, then torque off to adjust by hand.

    Torque goes on with goal = present, the servos ease to the key at the slow start speed
    (clamped to the rig's limits, Bus Watchdog on), and torque goes off once they are there,
    or on any stop (Ctrl-C, a fault): ``puppet perform``'s start, for one pose.

    \b
    Example:
      puppet keys goto shot.mcap 3 --rig my.toml --port /dev/ttyUSB0
    """
    from puppet.drive import DriveError, PerformOptions, perform
    from puppet.take import TakeReader

    rig = load_rig(rig_path)
    reader = TakeReader(shot)
    options = PerformOptions(key=index, yes=yes, watchdog=not no_watchdog,
                             watchdog_ms=watchdog_ms, baud=baud, latency_ms=latency_ms)
    try:
        report = perform(rig, reader, port, options, log=lambda line: click.echo(line, err=True))
    except DriveError as err:
        if err.report is not None:
            click.echo(err.report.text(), err=True)
        raise
    off = sorted(i for i, v in report.torque_after.items() if v == 0)
    click.echo(f"key {index}: {'reached' if report.stop_reason == 'end of take' else report.stop_reason}"
               f"; torque off on {len(off)} of {len(report.torque_after)} servos")


COMMANDS = (keys,)
