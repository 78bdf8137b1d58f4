"""Helpers shared by the commands: options, loading a rig or a take, running a session and printing it."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from puppet import limits
from puppet.errors import PuppetError


class InRange(click.ParamType):
    """A click type for a number checked against a puppet.limits.Range: nan, inf and values
    outside it are refused naming the option, the value and the range."""

    def __init__(self, limits) -> None:
        self.limits = limits
        self.name = "integer" if limits.integer else "float"

    def convert(self, value, param, ctx):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            number = value
        else:
            try:
                number = int(value) if self.limits.integer else float(value)
            except (TypeError, ValueError):
                self.fail(f"{value!r} is not {self.limits}", param, ctx)
        problem = self.limits.problem(number)
        if problem is not None:
            self.fail(problem, param, ctx)
        return number


def fail(message: str) -> None:
    """Exit 1 with 'Error: message' on stderr."""
    raise click.ClickException(message)


def load_rig(rig_path: str | None):
    """The rig at rig_path (the built-in character when None); errors name the file and field."""
    from puppet.rig import builtin, load_rig as load

    return builtin() if rig_path is None else load(rig_path)


def say(text: str) -> None:
    """A note on stderr (setup, outputs, warnings): stdout keeps the summary."""
    click.echo(text, err=True)


def print_setup(report, port: str) -> None:
    """Report what the bus setup found and changed (on stderr)."""
    from puppet.session.sources import setup_lines

    for line in setup_lines(report, port):
        say(line)


def run_session(session, *, as_json: bool = False, extra=None):
    """Run a live session (``puppet.session.Session``) and print its summary: the outputs'
    lines (take, video, link...), then ``extra(session)``'s, then the loop's figures; a run
    stopped by a signal says so on stderr. Returns the session."""
    session.run()
    if session.stopped_by is not None:
        say(f"stopped by {session.stopped_by} after {session.summary.frames} frames; "
            "every output holds what was made until then")
    lines = {**session.report(), **(extra(session) if extra is not None else {})}
    print_summary(session.summary, as_json, extra=lines)
    return session


space_option = click.option(
    "--space", type=click.Choice(["object", "model"]), default="object", show_default=True,
    help="Space of the PC2 points: object = the mesh object's local space, as Blender's "
         "glTF importer places the character (the Mesh Cache lands it on a moved or "
         "scaled character); model = the model frame (the file's world).")
keys_option = click.option(
    "--keys", default=None, type=InRange(limits.KEYS_DEG), metavar="DEG",
    help="glTF: per channel only the keys that reproduce the solved curve within DEG "
         f"degrees (rotations; {limits.KEYS_DEG}), LINEAR as Blender plays it; the "
         "report lists the keys kept per joint; a shot's key poses are keys on every channel. "
         "Default: a key on every frame. BVH, USD "
         "and PC2 keep every frame.")
keys_units_option = click.option(
    "--keys-units", default=None, type=InRange(limits.KEYS_UNITS), metavar="UNITS",
    help=f"With --keys: translations within UNITS model units ({limits.KEYS_UNITS}; "
         "default: the distance a DEG turn moves a point one bounding-box diagonal away).")
def sound_options(command):
    """--sound FILE, --sound-offset S and --count-in S: perform to a sound (live, record, keys)."""
    command = click.option(
        "--count-in", "count_in", default=0.0, type=InRange(limits.COUNT_IN_S), metavar="S",
        help=f"Seconds counted in (3, 2, 1) before the take's time 0 ({limits.COUNT_IN_S}); "
             "the take records, and the sound plays, from there.")(command)
    command = click.option(
        "--sound-offset", "sound_offset", default=0.0, type=InRange(limits.SOUND_OFFSET),
        metavar="S", help="Where in the sound the take's time 0 is, seconds.")(command)
    return click.option(
        "--sound", "sound_path", default=None, metavar="FILE",
        help="Perform to a sound (WAV, FLAC, OGG, MP3): it plays on this machine's sound device "
             "from the take's time 0, and the take stores which sound and where (its hash, "
             "offset and rate) for play and every export.")(command)


def sound_outputs(sound_path, sound_offset: float, count_in: float) -> list:
    """The session outputs of sound_options: the sound, and the count-in when there is one."""
    from puppet.session import outputs as o

    outputs = []
    if sound_path is not None:
        outputs.append(o.Sound(sound_path, offset_s=sound_offset, tell=say))
    if count_in > 0:
        outputs.append(o.CountIn(count_in, tell=say))
    return outputs


force_option = click.option(
    "--force", is_flag=True,
    help="Overwrite an existing output of another kind (an input, a device or a FIFO never).")


def progress(seconds: float | None, label: str):
    """A click progress bar over wall time, and the on_frame callback that advances it."""
    if seconds is None:
        return None, None
    bar = click.progressbar(length=max(1, int(seconds * 10)), label=label, file=sys.stderr)
    start = time.monotonic()
    shown = [0]

    def on_frame(_summary) -> None:
        done = min(bar.length, int((time.monotonic() - start) * 10))
        if done > shown[0]:
            bar.update(done - shown[0])
            shown[0] = done

    return bar, on_frame


class Null:
    """A context manager that does nothing (stands in for an absent progress bar)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def print_summary(summary, as_json: bool, extra: dict | None = None) -> None:
    """The loop summary as text or one JSON line, with extra key/values first."""
    if as_json:
        click.echo(json.dumps({**summary.as_dict(), **(extra or {})}))
        return
    for key, value in (extra or {}).items():
        click.echo(f"{key}: {value}")
    click.echo(summary.text())




def rig_files(rig) -> list[Path]:
    """The files a rig was loaded from (``puppet.rig.rig_file.loaded_files``)."""
    from puppet.rig.rig_file import loaded_files

    return loaded_files(rig)


def layer_options(strict: bool = True):
    """--mute, --solo and --punch of a layered take (play, export; batch: ``strict`` False, a
    take whose stack has none of the named layers plays as recorded): the command gets
    ``layers``, a ``puppet.take.layers.LayerOptions`` or None (every stack as recorded)."""
    import functools

    def decorate(command):
        @click.option("--mute", "mute", multiple=True, metavar="LAYER.mcap",
                      help="A layer of the take's stack that holds nothing: its base plays "
                           "through it (repeatable).")
        @click.option("--solo", "solo", default=None, metavar="LAYER.mcap",
                      help="The one layer of the stack that holds its joints (every other "
                           "muted).")
        @click.option("--punch", "punch", multiple=True, metavar="LAYER.mcap=IN:OUT",
                      help="Where a layer holds its joints, overriding its recorded punch: "
                           "seconds or marker names, either empty for the start / end "
                           "(repeatable).")
        @functools.wraps(command)
        def wrapped(*args, mute, solo, punch, **kwargs):
            from puppet.take.layers import LayerOptions

            return command(*args, layers=LayerOptions.from_flags(mute, solo, punch, strict),
                           **kwargs)

        return wrapped

    return decorate


def open_take(take: str, rig_path: str | None):
    """(rig, TakeReader) for a take; the rig is the take's own when --rig is not given."""
    from puppet.replay import open_take as open_on_rig

    rig, reader = open_on_rig(take, rig_path)
    if reader.recovery is not None:
        click.echo(f"warning: {take}: {reader.recovery}", err=True)
    return rig, reader

