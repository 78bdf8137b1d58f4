"""Helpers shared by the commands: loading a rig or a take, starting the reader, sinks, output."""

from __future__ import annotations

import json
import signal
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


def start_reader(rig, port: str, baud: int, rate_hz: float = 500.0, hook=None):
    """A started ReaderProcess reading the rig's servos on ``port``; reports what setup did.
    hook: its cycle hook (puppet.drive.actuators.ActuatorHook drives the rig's actuators)."""
    from puppet.bus.reader_process import ReaderProcess, ReaderProcessError

    if not rig.servo_map.ids.size:
        fail(f"{rig.path or rig.name}: the rig has no servos to read")
    source = ReaderProcess(port, rig.servo_map.models, rate_hz=rate_hz, baud=baud,
                           hook=hook)
    try:
        report = source.start()
    except ReaderProcessError as err:
        fail(str(err))  # it names the port
    print_setup(report, port)
    return source


def print_setup(report, port: str) -> None:
    """Report what the bus setup found and changed (on stderr)."""
    for note in report.notes:
        click.echo(note, err=True)
    if report.missing:
        click.echo(f"warning: servos {report.missing} did not answer on {port}; they are flagged "
                   "and probed until they appear", err=True)
    for change in report.changes:
        click.echo(f"servo {change.id}: {change.item} {change.old} -> {change.new}", err=True)


class StopFlag:
    """Set by SIGINT/SIGTERM so loops end cleanly and every sink is closed (a video gets its
    index: playable). A second signal while stopping raises KeyboardInterrupt (forced stop:
    outputs are then discarded, not left half written). ``signal_name`` names the first one."""

    def __init__(self):
        self.stop = False
        self.signal_name: str | None = None
        signal.signal(signal.SIGINT, self._set)
        signal.signal(signal.SIGTERM, self._set)

    def _set(self, signum, _frame):
        if self.stop:
            raise KeyboardInterrupt
        self.stop = True
        self.signal_name = signal.Signals(signum).name

    def __call__(self) -> bool:
        return self.stop


def make_sinks(out: str | None, frames: str | None, fps: float, inputs=(), *,
               force: bool = False) -> list:
    """Frame sinks for a video file and/or a PNG folder, after checking both by the one rule
    for outputs (``puppet.atomic``: not one of ``inputs``, not a device or FIFO, an existing file
    of another kind only with ``force``). The video is written to a temporary file and renamed
    into place when finished."""
    from puppet.atomic import check_folder_output, check_output
    from puppet.render import PngSink, VideoSink

    if out:
        check_output(out, kind="video", inputs=inputs, force=force, what="video")
    if frames:
        check_folder_output(frames)
    sinks = []
    if out:
        sinks.append(VideoSink(out, fps))
    if frames:
        Path(frames).mkdir(parents=True, exist_ok=True)
        sinks.append(PngSink(frames))
    return sinks


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
force_option = click.option(
    "--force", is_flag=True,
    help="Overwrite an existing output of another kind (an input, a device or a FIFO never).")


def close_sinks(sinks, *, failed: bool = False) -> None:
    """Close every sink (finishing its file), or abort them after a failure (``failed``): no half
    written video is renamed into place. The first sink error is raised after all are closed."""
    error = None
    for sink in sinks:
        try:
            if failed and hasattr(sink, "abort"):
                sink.abort()
            else:
                sink.close()
        except PuppetError as err:
            error = error or err
    if error is not None:
        raise error


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


def check_take_path(take_path: str, rig, *, force: bool) -> Path:
    """Refuse a take path that is one of the rig's files, a device or FIFO, or an existing file
    without --force (``puppet.atomic``'s rule)."""
    from puppet.atomic import check_output

    return check_output(take_path, kind="take", inputs=rig_files(rig), force=force,
                        keep_existing=True, what="take")


def take_writer(take_path: str, rig, *, force: bool = False):
    """A new TakeWriter for the rig's servos, with its rig map and calibration as metadata.

    An existing file at take_path is replaced only with force (--force); a rig file never.
    """
    from puppet.take import TakeWriter

    check_take_path(take_path, rig, force=force)
    return TakeWriter(take_path, **take_header(rig), overwrite=force)


def take_header(rig) -> dict:
    """What a take (or shot) of ``rig`` is written with: TakeWriter's ids, models, rig_map_text
    (the rig file, and where it was), calibration_text and rig_name."""
    from puppet.rig.checksum import character_sha256
    from puppet.replay import RIG_CHARACTER_MARK, RIG_SOURCE_MARK
    from puppet.rig.calibration import Calibration

    map_text = ""
    if rig.path is not None and rig.path.suffix == ".toml":
        map_text = rig.path.read_text(encoding="utf-8")
        map_text += ("" if map_text.endswith("\n") or not map_text else "\n")
        map_text += f"{RIG_CHARACTER_MARK}{character_sha256(rig)}\n"
        map_text += f"{RIG_SOURCE_MARK}{rig.path.resolve()}\n"
    calibration = Calibration.capture(rig.servo_map.ids, rig.servo_map.zero)
    return {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
            "rig_map_text": map_text, "calibration_text": calibration.to_record(),
            "rig_name": rig.name}


def open_take(take: str, rig_path: str | None):
    """(rig, TakeReader) for a take; the rig is the take's own when --rig is not given."""
    from puppet.replay import open_take as open_on_rig

    rig, reader = open_on_rig(take, rig_path)
    if reader.recovery is not None:
        click.echo(f"warning: {take}: {reader.recovery}", err=True)
    return rig, reader

