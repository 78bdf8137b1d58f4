"""``puppet keys``: capture key poses from the puppet into a shot, and retime or delete keys."""

from __future__ import annotations

import itertools
import sys
import threading
import time

import click

from puppet import limits
from puppet.cli.blender import link_option, open_link, report_link
from puppet.cli.common import InRange, StopFlag, check_take_path, load_rig, start_reader
from puppet.cli.view import view_option


def _lines(desk, finish_at_end: bool = True) -> None:
    """Press each stdin line (without its newline) on the KeyDesk, then ``q`` at end of input
    (finish_at_end; with --view the page goes on taking keys until q or Ctrl-C)."""
    from puppet.keys.capture import KeyRefused

    lines = (line.rstrip("\r\n") for line in sys.stdin)
    for line in itertools.chain(lines, ["q"] if finish_at_end else []):  # one at a time, as typed
        try:
            desk.press(line)
        except KeyRefused as err:
            click.echo(f"refused: {err}", err=True)


DEFAULT_FPS = 24.0
"""A new shot's frames per second (``--fps``; ``live --keys`` too)."""
DEFAULT_STEP = 12
"""Frames from a key to the next (``--step``; ``live --keys`` too)."""


def say_outcome(origin, taken: bool, words: str) -> None:
    """A key command's outcome on the terminal (refusals on stderr)."""
    click.echo(words, err=not taken)


@click.group(invoke_without_command=True)
@click.option("--rig", "rig_path", default=None, help="Rig file (TOML).")
@click.option("--port", default=None, help="Serial port.")
@click.option("--out", default=None, help="Shot file to write (.mcap).")
@click.option("--fps", default=DEFAULT_FPS, show_default=True, type=InRange(limits.FPS),
              help=f"The shot's frames per second ({limits.FPS}).")
@click.option("--step", default=DEFAULT_STEP, show_default=True, type=InRange(limits.KEY_STEP),
              help=f"Frames from a key to the next ({limits.KEY_STEP}).")
@click.option("--interpolation", default="linear", show_default=True,
              type=click.Choice(["linear", "smooth", "step"]),
              help="How in-betweens fill the frames after each key.")
@click.option("--baud", default=1_000_000, show_default=True, type=InRange(limits.BAUD),
              help=f"Bus speed: {limits.BAUD}.")
@click.option("--force", is_flag=True, help="Replace an existing shot file.")
@view_option
@link_option
@click.pass_context
def keys(ctx, rig_path, port, out, fps, step, interpolation, baud, force, view_address,
         link_address) -> None:
    """Pose to pose: hold a pose and press Enter; each key lands --step frames after the last.

    \b
    The key is the median of the readings over the 0.2 s after Enter (keep holding).
    Commands (a line each): Enter = new key, `r N` = replace key N with the held pose,
    `d N` = delete key N, `i F` = insert a key at frame F, `t N F` = retime key N to frame F,
    `m N KIND` = key N's interpolation (linear, smooth, step), `m KIND` = that of the keys to come,
    `q` (or Ctrl-C, end of input) = done.
    With --view the page takes keys too (Space or its Key button), shows the keys as ticks on a
    timeline (drag one to retime it) and the previous and next key as onion skins; end of input
    then does not finish (the page goes on): q or Ctrl-C does.
    The shot is a take with its keys: play, export and batch take it like any take.
    \b
    Examples:
      puppet keys --rig my.toml --port /dev/ttyUSB0 --out shot.mcap --fps 24 --step 12
      puppet keys --rig my.toml --port /dev/ttyUSB0 --out shot.mcap --view   (and the page)
      puppet keys --rig my.toml --port /dev/ttyUSB0 --out shot.mcap --view --link   (Blender)
      puppet keys retime shot.mcap 3=40 4=52 --out retimed.mcap
      puppet keys delete shot.mcap 2 --out fewer.mcap
      puppet keys interpolation shot.mcap 0=smooth 2=step --out smooth.mcap
      puppet keys goto shot.mcap 3 --rig my.toml --port /dev/ttyUSB0   (motorised puppets)
    """
    if ctx.invoked_subcommand is not None:
        return
    from puppet.cli.common import take_header
    from puppet.keys.capture import KeyDesk, KeySession

    missing = [name for name, value in (("--rig", rig_path), ("--port", port), ("--out", out))
               if value is None]
    if missing:
        raise click.UsageError(f"missing {', '.join(missing)} (or a command: retime, delete, interpolation, goto)")
    if link_address is not None and view_address is None:
        raise click.UsageError("--link streams the live loop that --view runs: add --view")
    from puppet.keys.shot import check_shot_path

    check_shot_path(out)
    rig = load_rig(rig_path)
    check_take_path(out, rig, force=force)  # before the port: a mistake costs nothing
    session = KeySession(out, take_header(rig), fps=fps, step=step, interpolation=interpolation)
    desk = KeyDesk(session, tell=say_outcome)
    link = None
    if view_address is not None:  # bound before the bus is touched: a taken port fails first
        link = open_link(link_address, rig) if link_address is not None else None
        try:
            source = _capture_in_view(rig, port, baud, desk, view_address, link)
        finally:
            if link is not None:
                link.close()
    else:
        source = _capture(rig, port, baud, desk)
    if session.written:
        frames = session.keys.keys[-1].frame if session.keys.keys else 0
        click.echo(f"shot: {out}\nkeys: {len(session.keys.keys)}, {frames} frames at {fps:g} fps")
    else:  # the shot is written at its first key: none taken, nothing written
        click.echo(f"shot: none: no key was taken, nothing written to {out}")
    from puppet.events import describe_counts

    click.echo(f"faults seen: {describe_counts(dict(source.log.counts))}")  # the summary's words
    if link is not None:
        click.echo(f"link: {report_link(link)['link']}")


def _capture(rig, port: str, baud: int, desk):
    """Take the terminal's commands until q, end of input or Ctrl-C; returns the reader."""
    source = start_reader(rig, port, baud, rate_hz=200.0)
    threading.Thread(target=_lines, args=(desk,), daemon=True).start()
    stop = StopFlag()
    click.echo("hold a pose and press Enter for a key (r N, d N, i FRAME, t N FRAME, m [N] KIND, q: see --help)")
    try:
        while not stop() and not desk.finished:
            desk.feed(source.drain())
            desk.step()
            time.sleep(0.005)
    finally:
        source.stop()
    return source


def _capture_in_view(rig, port: str, baud: int, desk, address: str, link=None):
    """The capture inside the live view: the live loop solves and shows the puppet, the view
    hands the KeyDesk its readings and the page's keys; the terminal's commands work as well.
    link: a Link (``--link``) fed every solved frame of that loop, or None."""
    from puppet.cli.view import open_view
    from puppet.loop import Pipeline, run_live
    from puppet.loop.run import LIVE_FPS

    live_view = open_view(address, mode="live", keys=desk)
    stop = StopFlag()
    try:
        with Pipeline(rig, overlay=True, live=True) as pipeline:
            source = start_reader(rig, port, baud, rate_hz=200.0)
            try:
                live_view.attach(pipeline, source=source)
                if link is not None:
                    link.attach(pipeline, fps=LIVE_FPS)
                threading.Thread(target=_lines, args=(desk, False), daemon=True).start()
                click.echo("hold a pose and press Enter here, or Space or Key on the page, for a "
                           "key (r N, d N, i FRAME, t N FRAME, m [N] KIND, q: see --help)")
                run_live(pipeline, source, should_stop=lambda: stop() or desk.finished,
                         view=live_view, link=link)
            finally:
                live_view.close()
                source.stop()
    finally:
        live_view.close()
    return source


def _edit(shot: str, out: str, force: bool, change) -> None:
    """Read ``shot``, apply ``change(keys) -> keys``, write the result to ``out`` (the output
    rule: never the input, an existing file only with --force)."""
    from puppet.atomic import check_output
    from puppet.keys import read_shot, write_shot
    from puppet.keys.shot import check_shot_path

    check_shot_path(out)
    header, keys, reader = read_shot(shot)
    if reader.recovery is not None:
        click.echo(f"warning: {shot}: {reader.recovery}", err=True)
    target = check_output(out, kind="take", inputs=[shot], force=force, keep_existing=True,
                          what="shot")
    new = change(keys)
    write_shot(target, header, new)
    click.echo(f"shot: {out}\nkeys: " + ", ".join(f"{k.id}@{k.frame} {k.interpolation}"
                                                 for k in new.keys))


@keys.command()
@click.argument("shot")
@click.argument("moves", nargs=-1, required=True)
@click.option("--out", required=True, help="The retimed shot (.mcap; not the input).")
@click.option("--force", is_flag=True, help="Replace an existing file at --out.")
def retime(shot: str, moves: tuple[str, ...], out: str, force: bool) -> None:
    """Move keys to new frames: KEY=FRAME ... (refused if keys would reorder or share a frame,
    or a key would land past the shot's length, puppet.limits.SHOT_SECONDS: 1 h).

    KEY is a key's id as `puppet keys` prints it (0, 1, 2, ... as taken): ids stay with their
    keys across edits (a deleted key's id is not reused; a damaged key skipped on reading
    renumbers nothing and stays in the output file).

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
@click.argument("index", type=InRange(limits.KEY_INDEX))
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
@click.argument("index", type=InRange(limits.KEY_INDEX))
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
