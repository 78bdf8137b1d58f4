"""``puppet keys``: capture key poses from the puppet into a shot, and retime or delete keys."""

from __future__ import annotations

import itertools
import sys

import click

from puppet import limits
from puppet.cli.blender import link_option
from puppet.cli.common import InRange, load_rig, rig_files, run_session, say
from puppet.cli.view import view_option


def _lines_then_q(desk) -> None:
    """The terminal's commands, then q at end of input (no view: the shot is done)."""
    _lines(desk, finish_at_end=True)


def _lines_only(desk) -> None:
    """The terminal's commands; end of input does not finish (the page goes on taking keys)."""
    _lines(desk, finish_at_end=False)


def new_desk(rig, path: str, *, fps: float = None, step: int = None,
             interpolation: str = "linear", sound=None):
    """A KeyDesk for a new shot of ``rig`` at ``path`` (``puppet keys``' defaults), its
    outcomes said on the terminal. sound: the shot's SoundRef (the sound's time at frame 1)."""
    from puppet.keys.capture import KeyDesk, KeySession
    from puppet.take.header import take_header

    header = take_header(rig)
    if sound is not None:
        header["sound"] = sound
    session = KeySession(path, header, fps=DEFAULT_FPS if fps is None else fps,
                         step=DEFAULT_STEP if step is None else step, interpolation=interpolation)
    return KeyDesk(session, tell=say_outcome)


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
@click.option("--sound", "sound_path", default=None, metavar="FILE",
              help="Key to a sound (WAV, FLAC, OGG, MP3): the shot stores which sound and where "
                   "(--sound-offset: its time at frame 1), for play and every export.")
@click.option("--sound-offset", "sound_offset", default=0.0, type=InRange(limits.SOUND_OFFSET),
              metavar="S", help="The sound's time at the shot's frame 1, seconds.")
@view_option
@link_option
@click.pass_context
def keys(ctx, rig_path, port, out, fps, step, interpolation, baud, force, view_address,
         link_address, sound_path, sound_offset) -> None:
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
    from puppet.events import describe_counts
    from puppet.session import Session
    from puppet.session import outputs as o
    from puppet.session.sources import BusSource

    missing = [name for name, value in (("--rig", rig_path), ("--port", port), ("--out", out))
               if value is None]
    if missing:
        raise click.UsageError(f"missing {', '.join(missing)} (or a command: retime, delete, interpolation, goto)")
    if link_address is not None and view_address is None:
        raise click.UsageError("--link streams the live loop that --view runs: add --view")
    from puppet.keys.shot import check_shot_path

    check_shot_path(out)
    rig = load_rig(rig_path)
    sound = None
    if sound_path is not None:
        from puppet.sound import load_sound, sound_ref

        sound = sound_ref(load_sound(sound_path), sound_offset)
    desk = new_desk(rig, out, fps=fps, step=step, interpolation=interpolation, sound=sound)
    in_view = view_address is not None
    ready = ("hold a pose and press Enter here, or Space or Key on the page, for a key "
             "(r N, d N, i FRAME, t N FRAME, m [N] KIND, q: see --help)" if in_view else
             "hold a pose and press Enter for a key (r N, d N, i FRAME, t N FRAME, m [N] KIND, "
             "q: see --help)")
    outputs = [o.KeyDesk(desk, path=out, rig=rig, feed=not in_view, force=force, option="--out",
                         lines=_lines_only if in_view else _lines_then_q, ready_text=ready,
                         tell=click.echo)]
    if link_address is not None:
        outputs.append(o.Link(link_address, rig, tell=say))
    if in_view:
        outputs.append(o.View(view_address, mode="live", keys=desk, tell=say))
    session = Session(rig, BusSource(rig, port, baud=baud, rate_hz=200.0), outputs,
                      inputs=[*rig_files(rig), sound_path], solve=in_view, tell=say,
                      latch_fps=None if not in_view else 60.0,
                      pipeline={"overlay": True, "live": True})
    session.run()
    click.echo("\n".join(f"{key}: {value}" for key, value in session.report().items()))
    click.echo(f"faults seen: {describe_counts(session.summary.faults)}")


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
            raise click.BadParameter(f"{index}={frame}: FRAME is a whole number from 1, e.g. 3=40")
        frames[index] = int(frame)
    _edit(shot, out, force, lambda k: retime_keys(k, frames, shot))


def _pairs(items: tuple[str, ...], right: str, example: str) -> dict[int, str]:
    """{index: value} of INDEX=VALUE arguments; BadParameter naming a malformed one, or a key
    given twice (which one was meant is not for us to guess)."""
    pairs: dict[int, str] = {}
    given: dict[int, str] = {}
    for item in items:
        index, _, value = item.partition("=")
        if not index.strip().isdigit() or not value.strip():
            raise click.BadParameter(f"{item!r}: expected INDEX={right}, e.g. {example}")
        key = int(index)
        if key in pairs:
            raise click.BadParameter(f"key {key} given twice ({given[key]!r} and {item!r}): "
                                     "give each key once")
        pairs[key], given[key] = value.strip(), item
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
