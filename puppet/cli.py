"""The puppet command line. Nothing imports this module; it imports the parts it runs."""

from __future__ import annotations

import os

# On a small machine OpenBLAS worker threads busy-wait after every numpy call and steal the
# core the solver, the renderer and the bus reader need; puppet's numpy work is small.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import json  # noqa: E402
import signal
import sys
import time
from pathlib import Path

import click
import numpy as np


def _fail(message: str) -> None:
    """Exit 1 with 'Error: message' on stderr."""
    raise click.ClickException(message)


def _load_rig(rig_path: str | None):
    """The rig at rig_path (the built-in character when None); errors name the file and field."""
    from puppet.rig import RigError, builtin, load_rig

    try:
        return builtin() if rig_path is None else load_rig(rig_path)
    except RigError as err:
        _fail(str(err))


def _start_reader(rig, port: str, baud: int, rate_hz: float = 500.0):
    """A started ReaderProcess reading the rig's servos on ``port``; reports what setup did."""
    from puppet.bus.reader_process import ReaderProcess, ReaderProcessError

    if not rig.servo_map.ids.size:
        _fail(f"{rig.path or rig.name}: the rig has no servos to read")
    source = ReaderProcess(port, rig.servo_map.models, rate_hz=rate_hz, baud=baud)
    try:
        report = source.start()
    except ReaderProcessError as err:
        _fail(f"port {port}: {err}")
    _print_setup(report, port)
    return source


def _print_setup(report, port: str) -> None:
    if report.missing:
        click.echo(f"warning: servos {report.missing} did not answer on {port}; they are flagged "
                   "and probed until they appear", err=True)
    for change in report.changes:
        click.echo(f"servo {change.id}: {change.item} {change.old} -> {change.new}", err=True)


class _StopFlag:
    """Set by SIGINT/SIGTERM so loops end cleanly and every sink is closed."""

    def __init__(self):
        self.stop = False
        signal.signal(signal.SIGINT, self._set)
        signal.signal(signal.SIGTERM, self._set)

    def _set(self, *_):
        self.stop = True

    def __call__(self) -> bool:
        return self.stop


def _sinks(out: str | None, frames: str | None, fps: float) -> list:
    from puppet.render import PngSink, SinkError, VideoSink

    sinks = []
    try:
        if out:
            sinks.append(VideoSink(out, fps))
        if frames:
            Path(frames).mkdir(parents=True, exist_ok=True)
            sinks.append(PngSink(frames))
    except SinkError as err:
        _fail(str(err))
    return sinks


def _progress(seconds: float | None, label: str):
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


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="puppet")
def main() -> None:
    """Turn a posed puppet of Dynamixel servos into rendered character animation.

    \b
    Examples:
      puppet demo                          built-in character on a simulated bus
      puppet rig info --json               check the built-in rig
      hw-sim --servos 1-15 &               a simulated bus; prints its port
      puppet scan --port /dev/ttyUSB0
      puppet calibrate --rig my.toml --port /dev/ttyUSB0
      puppet live --rig my.toml --port /dev/ttyUSB0 --record take.mcap --out live.mp4
      puppet play take.mcap --out take.mp4 --speed 0.5
      puppet export take.mcap --pc2 mesh.pc2 --bvh skeleton.bvh
    """


@main.command()
@click.option("--out", default="demo.mp4", show_default=True, help="Video file to write.")
@click.option("--seconds", default=10.0, show_default=True, type=click.FloatRange(min=0.1),
              help="Length of the run.")
@click.option("--faults", default=None, type=click.Path(exists=True, dir_okay=False),
              help="hw_sim fault file to play during the run.")
@click.option("--size", default=(640, 480), type=(int, int), show_default=True, help="Frame size.")
@click.option("--fps", default=30.0, show_default=True, help="Video frame rate.")
@click.option("--antialias", type=click.Choice(["auto", "msaa", "fxaa", "none"]), default="auto",
              show_default=True, help="auto: MSAA on a GPU, none on a software renderer.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def demo(out: str, seconds: float, faults: str | None, size: tuple[int, int], fps: float,
         antialias: str, as_json: bool) -> None:
    """Run the live loop on the built-in character and a simulated bus, into a video.

    \b
    Example:
      puppet demo --seconds 5 --out demo.mp4
    """
    from puppet.demo import run_demo

    bar, on_frame = _progress(seconds, "demo")
    with bar if bar is not None else _Null():
        summary, report = run_demo(seconds=seconds, faults=faults, width=size[0], height=size[1],
                                   video_fps=fps, on_frame=on_frame, antialias=antialias,
                                   sinks_for=lambda _p: _sinks(out, None, fps))
    _print_summary(summary, as_json, extra={"video": out, "read_mode": report.read_mode})


class _Null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _print_summary(summary, as_json: bool, extra: dict | None = None) -> None:
    if as_json:
        click.echo(json.dumps({**summary.as_dict(), **(extra or {})}))
        return
    for key, value in (extra or {}).items():
        click.echo(f"{key}: {value}")
    click.echo(summary.text())


@main.command()
@click.option("--rig", "rig_path", required=True, help="Rig file (TOML).")
@click.option("--port", required=True, help="Serial port, e.g. /dev/ttyUSB0 or hw-sim's pty.")
@click.option("--baud", default=1_000_000, show_default=True, help="Bus baud rate.")
@click.option("--record", "take_path", default=None, help="Also record a take here (.mcap).")
@click.option("--out", default=None, help="Video file to write.")
@click.option("--frames", default=None, help="Folder for PNG frames.")
@click.option("--seconds", default=None, type=float, help="Stop after this long (default: Ctrl-C).")
@click.option("--fps", default=30.0, show_default=True, help="Video frame rate.")
@click.option("--antialias", type=click.Choice(["auto", "msaa", "fxaa", "none"]), default="auto",
              show_default=True, help="auto: MSAA on a GPU, none on a software renderer.")
def live(rig_path: str, port: str, baud: int, take_path: str | None, out: str | None,
         frames: str | None, seconds: float | None, fps: float, antialias: str) -> None:
    """Read the puppet, solve and render live until Ctrl-C.

    \b
    Example:
      puppet live --rig my.toml --port /dev/ttyUSB0 --record take.mcap --out live.mp4
    """
    from puppet.pipeline import Pipeline, run_live
    from puppet.take import BackgroundTakeWriter

    rig = _load_rig(rig_path)
    sinks = _sinks(out, frames, fps)
    stop = _StopFlag()
    with Pipeline(rig, render=bool(sinks), overlay=True, antialias=antialias) as pipeline:
        source = _start_reader(rig, port, baud)
        try:
            # On its own thread: a periodic fsync must not stall a frame.
            recorder = BackgroundTakeWriter(_take_writer(take_path, rig)) if take_path else None
            try:
                summary = run_live(pipeline, source, seconds=seconds, sinks=sinks, video_fps=fps,
                                   recorder=recorder, should_stop=stop)
            finally:
                if recorder is not None:
                    recorder.close()
        finally:
            for sink in sinks:
                sink.close()
            source.stop()
    _print_summary(summary, False, extra={"take": take_path} if take_path else None)


def _take_writer(take_path: str, rig):
    from puppet.take import TakeError, TakeWriter

    map_text = rig.path.read_text() if rig.path is not None and rig.path.suffix == ".toml" else ""
    calibration = {str(i): int(z) for i, z in zip(rig.servo_map.ids, rig.servo_map.zero)}
    try:
        return TakeWriter(take_path, ids=[int(i) for i in rig.servo_map.ids],
                          models=dict(rig.servo_map.models), rig_map_text=map_text,
                          calibration_text=json.dumps({"zero_ticks": calibration}),
                          rig_name=rig.name, overwrite=True)
    except TakeError as err:
        _fail(str(err))


@main.command()
@click.option("--rig", "rig_path", required=True, help="Rig file (TOML).")
@click.option("--port", required=True, help="Serial port.")
@click.option("--out", required=True, help="Take file to write (.mcap).")
@click.option("--baud", default=1_000_000, show_default=True, help="Bus baud rate.")
@click.option("--seconds", default=None, type=float, help="Stop after this long (default: Ctrl-C).")
@click.option("--rate", default=500.0, show_default=True, help="Readings per second.")
def record(rig_path: str, port: str, out: str, baud: int, seconds: float | None, rate: float) -> None:
    """Record a take (raw servo readings) without solving or rendering: the lightest loop.

    \b
    Example:
      puppet record --rig my.toml --port /dev/ttyUSB0 --out take.mcap --seconds 30
    """
    rig = _load_rig(rig_path)
    writer = _take_writer(out, rig)
    source = _start_reader(rig, port, baud, rate_hz=rate)
    stop = _StopFlag()
    start = time.monotonic()
    count = flagged = 0
    try:
        while not stop() and (seconds is None or time.monotonic() - start < seconds):
            batch = source.drain()
            if not batch:
                time.sleep(0.005)
            for reading in batch:
                writer.write(reading)
                count += 1
                flagged += int(not reading.ok.all())
    finally:
        writer.close()
        source.stop()
    click.echo(f"take: {out}\nreadings: {count} in {time.monotonic() - start:.2f} s, "
               f"{flagged} with a flagged servo\nfaults seen: {dict(source.log.counts) or 'none'}")


def _open_take(take: str, rig_path: str | None):
    """(rig, TakeReader) for a take; the rig is the take's own when --rig is not given."""
    from puppet.rig import Calibration
    from puppet.take import TakeError, TakeReader

    try:
        reader = TakeReader(take)
    except TakeError as err:
        _fail(str(err))
    if len(reader) == 0:
        _fail(f"{take}: the take holds no readings")
    meta = reader.metadata
    if rig_path is None:
        rig = _load_rig(None)
        if meta.rig_name != rig.name:
            _fail(f"{take}: recorded with rig {meta.rig_name!r}; pass --rig with that rig's file")
    else:
        rig = _load_rig(rig_path)
    try:
        reader.check_rig([int(i) for i in rig.servo_map.ids], dict(rig.servo_map.models))
    except TakeError as err:
        _fail(str(err))
    try:  # replay with the calibration the take was recorded with
        zero = json.loads(meta.calibration_text).get("zero_ticks", {}) if meta.calibration_text else {}
        if zero:
            rig.servo_map.calibrate(Calibration({int(k): int(v) for k, v in zero.items()}))
    except (ValueError, AttributeError) as err:
        _fail(f"{take}: unreadable calibration in the take: {err}")
    if reader.truncated:
        click.echo(f"warning: {take}: {reader.recovery}", err=True)
    return rig, reader


@main.command()
@click.argument("take")
@click.option("--rig", "rig_path", default=None, help="Rig to replay on (default: the take's).")
@click.option("--out", default=None, help="Video file to write.")
@click.option("--frames", default=None, help="Folder for PNG frames.")
@click.option("--speed", default=1.0, show_default=True, type=click.FloatRange(min=0.01),
              help="Playback speed factor.")
@click.option("--fps", default=30.0, show_default=True, help="Output frame rate.")
@click.option("--antialias", type=click.Choice(["msaa", "fxaa", "none"]), default="msaa",
              show_default=True, help="Offline: MSAA by default, whatever the renderer.")
def play(take: str, rig_path: str | None, out: str | None, frames: str | None, speed: float,
         fps: float, antialias: str) -> None:
    """Replay a take through the solver and renderer (deterministic).

    \b
    Example:
      puppet play take.mcap --out take.mp4 --speed 0.5
    """
    from puppet.pipeline import Pipeline, run_frames
    from puppet.take import PlaybackClock

    if not out and not frames:
        _fail("nothing to write: give --out VIDEO and/or --frames FOLDER")
    rig, reader = _open_take(take, rig_path)
    sinks = _sinks(out, frames, fps)
    ids = [int(i) for i in rig.servo_map.ids]
    try:
        with Pipeline(rig, overlay=True, antialias=antialias) as pipeline:
            clock = PlaybackClock(reader.readings(ids=ids), fps=fps, speed=speed)
            total = clock.frame_count(reader.t_last_ns - reader.t_first_ns)
            with click.progressbar(length=total, label="play", file=sys.stderr) as bar:
                summary = run_frames(pipeline, (f.reading for f in clock), sinks=sinks,
                                     on_frame=lambda _p: bar.update(1))
    finally:
        for sink in sinks:
            sink.close()
    _print_summary(summary, False, extra={"take": take, "video": out} if out else {"take": take})


@main.command()
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
        _fail(f"port {port}: {err}")
    finally:
        link.close()
    if not found:
        _fail(f"port {port}: no servo answered a broadcast ping at {baud} bps")
    click.echo(f"{'id':>4}  {'model':<12} {'number':>6}  firmware")
    for dxl_id, (number, firmware) in sorted(found.items()):
        model = MODELS_BY_NUMBER.get(number)
        click.echo(f"{dxl_id:>4}  {model.name if model else 'unknown':<12} {number:>6}  {firmware}")


@main.command()
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
    from puppet.rig import Calibration, RigError

    rig = _load_rig(rig_path)
    target = out or rig.calibration.path
    if target is None:
        _fail(f"{rig_path}: the rig names no calibration file; pass --out FILE")
    reader = ServoReader(port, rig.servo_map.models, baud=baud)
    try:
        _print_setup(reader.open(), port)
        reading = reader.read_clean(samples=9, timeout_s=3.0)
    except BusError as err:
        _fail(f"port {port}: {err}")
    finally:
        reader.close()
    try:
        path = Calibration.capture(reading.ids, reading.ticks).save(target)
    except RigError as err:
        _fail(str(err))
    click.echo(f"calibration: {path}")
    for dxl_id, ticks in zip(reading.ids, reading.ticks):
        click.echo(f"  servo {int(dxl_id)}: zero {int(ticks)}")


@main.command()
@click.argument("take")
@click.option("--rig", "rig_path", default=None, help="Rig to solve on (default: the take's).")
@click.option("--pc2", default=None, help="Point cache of the deformed mesh (Blender Mesh Cache).")
@click.option("--bvh", default=None, help="Sensed joint rotations as BVH.")
@click.option("--fps", default=30.0, show_default=True, help="Samples per second.")
def export(take: str, rig_path: str | None, pc2: str | None, bvh: str | None, fps: float) -> None:
    """Export a take as a mesh point cache (PC2) and a BVH skeleton.

    \b
    Example:
      puppet export take.mcap --pc2 mesh.pc2 --bvh skeleton.bvh
    """
    from puppet.export import BvhWriter, ExportError, Pc2Writer
    from puppet.pipeline import Pipeline, run_frames
    from puppet.take import PlaybackClock

    if not pc2 and not bvh:
        _fail("nothing to write: give --pc2 FILE and/or --bvh FILE")
    rig, reader = _open_take(take, rig_path)
    sk = rig.skeleton
    ids = [int(i) for i in rig.servo_map.ids]
    writers = []
    try:
        with Pipeline(rig, render=False) as pipeline:
            if pc2:
                cache = Pc2Writer(pc2, len(rig.V), sample_rate=1.0)
                writers.append(cache)
            if bvh:
                offsets = sk.heads - np.where(sk.parents[:, None] >= 0, sk.heads[sk.parents], 0.0)
                motion = BvhWriter(bvh, names=list(sk.names), parents=sk.parents, offsets=offsets,
                                   frame_time=1.0 / fps)
                writers.append(motion)
                rotations = np.empty((sk.bone_count, 3, 3))

            clock = PlaybackClock(reader.readings(ids=ids), fps=fps)
            bar = click.progressbar(length=clock.frame_count(reader.t_last_ns - reader.t_first_ns),
                                    label="export", file=sys.stderr)

            def write(p: Pipeline) -> None:
                bar.update(1)
                if pc2:
                    cache.write(p.deformed().astype(np.float32))
                if bvh:
                    motion.write(sk.joint_rotations(p.angles, rotations))

            with bar:
                summary = run_frames(pipeline, (f.reading for f in clock), on_frame=write)
    except ExportError as err:
        _fail(str(err))
    finally:
        for w in writers:
            w.close()
    click.echo(f"frames: {summary.frames}" + (f"\npc2: {pc2}" if pc2 else "") + (f"\nbvh: {bvh}" if bvh else ""))


@main.group()
def rig() -> None:
    """Inspect rigs."""


@rig.command("info")
@click.argument("rig_path", required=False)
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def rig_info(rig_path: str | None, as_json: bool) -> None:
    """Vertices, bones, servos and constraint kinds of a rig (built-in when omitted)."""
    import json
    import time

    from puppet.rig import RigError, builtin, load_rig

    start = time.perf_counter()
    try:
        loaded = builtin() if rig_path is None else load_rig(rig_path)
    except RigError as err:
        raise click.ClickException(str(err)) from None
    load_s = time.perf_counter() - start
    kinds = loaded.bone_kinds()
    report = loaded.check_weights()
    info = {"name": loaded.name, "vertices": len(loaded.V), "triangles": len(loaded.F),
            "bones": loaded.skeleton.bone_count, "servos": len(loaded.servo_map),
            "full": kinds["full"], "relative": kinds["relative"], "free": kinds["free"],
            "weights_ok": report.ok, "load_s": round(load_s, 4)}
    if as_json:
        click.echo(json.dumps(info))
        return
    click.echo(f"rig        {loaded.name} ({loaded.path or 'built-in'})")
    click.echo(f"vertices   {info['vertices']}")
    click.echo(f"triangles  {info['triangles']}")
    click.echo(f"bones      {info['bones']}")
    click.echo(f"servos     {info['servos']}: " + ", ".join(
        f"{s.id}:{s.model}->{s.joint}" for s in loaded.servo_map.servos))
    for kind in ("full", "relative", "free"):
        click.echo(f"{kind:<10} {', '.join(kinds[kind]) or '-'}")
    click.echo(f"pins       {len(loaded.pins)}")
    opts = loaded.solver_options
    click.echo(f"solver     clusters={opts.clusters} extra_weights={opts.extra_weights} energy={opts.energy}")
    click.echo(f"weights    {report.summary()}")
    click.echo(f"load       {load_s:.3f} s")


if __name__ == "__main__":
    main()
