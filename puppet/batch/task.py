"""One take, solved and written in a worker: the task every engine runs.

The worker writes the take's outputs into a private staging folder, each through
``puppet.atomic`` (a temporary name, renamed when whole), with the very functions ``puppet
export`` (``export_take``, ``ExportWriters``) and ``puppet play`` (``play_take``) call, so the
bytes are the same as running those commands on the take alone. A take is solved once for all
its formats: with a video, the exports are written from the same solved frames as it. The driver then moves them into the output folder
(local engine) or receives their bytes and writes them (Ray). A worker killed mid-take leaves
only its staging folder, which the driver removes.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from puppet.atomic import atomic_output
from puppet.batch.plan import Job
from puppet.batch.row import TakeResult
from puppet.errors import PuppetError
from puppet.loop import RigPrecompute
from puppet.rig import Rig
from puppet.take.layers import LayerOptions

EXPORT_FORMATS = ("gltf", "usd", "pc2", "bvh")


@dataclass(frozen=True)
class Settings:
    """What every take is made with. formats: of plan.FORMATS; fps: frames per second of every
    output; up: PC2 up axis ('y' or 'z'); size: (width, height) pixels of the mp4; antialias:
    as ``puppet play --antialias`` (msaa by default, offline quality); space: the PC2's points'
    space as ``puppet export --space``; keys, keys_units: glTF key reduction as ``puppet export
    --keys/--keys-units`` (None: a key on every frame); layers: a layered take's
    ``LayerOptions`` as ``--mute/--solo/--punch`` (None: every stack as recorded)."""

    formats: tuple[str, ...]
    fps: float = 30.0
    up: str = "y"
    space: str = "object"
    size: tuple[int, int] = (640, 480)
    antialias: str = "msaa"
    keys: float | None = None
    keys_units: float | None = None
    layers: LayerOptions | None = None


@dataclass
class Shared:
    """Sent once to every worker (pickled; on Ray put once in the object store).

    rigs: {``plan.TakeRig.key``: (rig, precompute)}: every rig the batch's takes are solved on
    (``Job.rig_key`` picks one), uncalibrated (each take applies its own recorded calibration to
    a copy), with its FastModel and factorization, never recomputed per take; settings: see
    Settings.
    """

    rigs: dict[str, tuple[Rig, RigPrecompute]]
    settings: Settings


TIMEOUT_BASE_S = 120.0
TIMEOUT_PER_SECOND = 60.0
"""The default --take-timeout: TIMEOUT_BASE_S + TIMEOUT_PER_SECOND x the take's length in
seconds (a 10 s take: 12 min). A video costs about 1 CPU second per second of take here (render
and encode, docs/scale.md), exports far less: the default is for a machine tens of times slower
or busier, while a hung take still frees its worker."""


def take_timeout_s(take: Path, limit_s: float | None) -> float:
    """Seconds a take may run: ``limit_s`` (--take-timeout) when given, else the default scaled
    by the take's length (a take that cannot be read gets the base: it fails at once anyway)."""
    if limit_s is not None:
        return float(limit_s)
    from puppet.take import TakeReader

    if not take.is_file():  # a FIFO would block the driver: the task reports it
        return TIMEOUT_BASE_S
    try:
        with TakeReader(take) as reader:
            seconds = reader.duration_s
    except (PuppetError, OSError):  # a bad take: the task reports it, in its row, at once
        return TIMEOUT_BASE_S
    return TIMEOUT_BASE_S + TIMEOUT_PER_SECOND * seconds


TRACEBACK_LINES = 8
"""Lines of a worker's traceback (its end) kept in a failed take's log."""


def internal_error(take, err: BaseException, *, worker: str = "",
                   traceback_text: str | None = None) -> TakeResult:
    """The failed row of a take whose worker raised what no take should (a bug, not a bad take):
    the reason names the exception and where it was raised (file:line in function); the log
    lines hold the end of the worker's own traceback. The same on every engine.
    traceback_text: the worker's traceback as text, for an exception that crossed a process
    (its ``__traceback__`` did not: Ray's ``RayTaskError.traceback_str``)."""
    import re
    import traceback

    if traceback_text is None:
        frames = traceback.extract_tb(err.__traceback__)
        where = f" (at {Path(frames[-1].filename).name}:{frames[-1].lineno} in " \
                f"{frames[-1].name})" if frames else ""
        traceback_text = "".join(traceback.format_exception(type(err), err,
                                                            err.__traceback__))
    else:
        frames = re.findall(r'File "([^"]+)", line (\d+), in (\S+)', traceback_text)
        where = f" (at {Path(frames[-1][0]).name}:{frames[-1][1]} in {frames[-1][2]})" \
            if frames else ""
    said = next((line for line in str(err).splitlines() if line.strip()), "")  # one line
    result = TakeResult.failed(take, f"internal error: {type(err).__name__}: {said}{where}",
                               worker=worker)
    result.add_log("the worker's traceback (its end):")
    for line in traceback_text.rstrip().splitlines()[-TRACEBACK_LINES:]:
        result.add_log(line)
    return result


def staging_folder(root: Path, job: Job) -> Path:
    """The worker's private folder for a take: ``root/<take name>.<pid>`` (a retry gets its own)."""
    folder = root / f"{job.name}.{os.getpid()}"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@contextlib.contextmanager
def captured_output(path: Path):
    """This process's stdout and stderr (file descriptors 1 and 2: Python's prints and
    warnings, native libraries, Ray's worker lines) go to the file ``path`` inside."""
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    saved = [os.dup(1), os.dup(2)]
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for f in (fd, *saved):
            os.close(f)


def run_take_logged(job: Job, shared: Shared, staging: Path) -> TakeResult:
    """``run_take`` with whatever the worker prints meanwhile kept in the row's log lines
    (colour codes removed), for the take's log file: nothing raw reaches the terminal."""
    output = staging / ".output"
    with captured_output(output):
        result = run_take(job, shared, staging)
    try:
        text = output.read_text(errors="replace")
    except OSError:
        text = ""
    for line in text.splitlines():
        if line.strip():
            result.add_log(line)
    return result


def run_take(job: Job, shared: Shared, staging: Path) -> TakeResult:
    """Solve ``job``'s take on the shared rig and write its outputs into ``staging``.

    A bad take (corrupt, foreign, empty) is a row in state failed with the reason, never an
    exception.
    """
    from puppet.export import ExportWriters, Outputs, export_take
    from puppet.export.run import check_size, estimated_bytes, take_frames
    from puppet.render import VideoSink
    from puppet.replay import open_take, play_take

    start, cpu = time.perf_counter(), time.process_time()
    result = TakeResult(take=str(job.take), worker=f"{os.uname().nodename}:{os.getpid()}")
    settings = shared.settings
    names = {fmt: target.name for fmt, target in job.outputs.items()}
    try:
        rig, precompute = shared.rigs[job.rig_key]
        rig, reader = open_take(job.take, rig)
        if reader.recovery is not None:
            result.warnings.append(str(reader.recovery))
        exports = Outputs(**{fmt: staging / names[fmt] for fmt in EXPORT_FORMATS if fmt in names})
        if "mp4" not in names:
            report = export_take(rig, reader, exports, fps=settings.fps, up=settings.up,
                                 space=settings.space, keys=settings.keys,
                                 keys_units=settings.keys_units,
                                 precompute=precompute, layers=settings.layers)
            result.frames = report.frames
            result.add_report(report)
        else:  # one solve of every frame: the video and every export from the same T
            frames = take_frames(rig, reader, settings.fps, layers=settings.layers)
            width, height = settings.size  # the size rule, as play's (before anything is written)
            check_size(job.outputs["mp4"], "the mp4 output", estimated_bytes(
                "mp4", len(frames), pixels=width * height),
                f"{len(frames)} frames of {width}x{height} at {settings.fps:g} fps", False)
            with contextlib.ExitStack() as stack:
                writers = [stack.enter_context(ExportWriters(
                    rig, reader, exports, frames, up=settings.up, space=settings.space,
                    keys=settings.keys,
                    keys_units=settings.keys_units))
                           ] if exports.items() else []
                with atomic_output(staging / names["mp4"], kind="video") as temporary:
                    sink = VideoSink(temporary, settings.fps)
                    try:
                        summary = play_take(rig, reader, [sink], frames=frames, solved=writers,
                                            antialias=settings.antialias, size=settings.size,
                                            precompute=precompute)
                    except BaseException:  # a failure, or the worker stopped: encoder killed
                        sink.abort()
                        raise
                    sink.close()
            result.frames = summary.frames
            for writer in writers:  # the exports' report: keys kept, fits, what was not carried
                result.add_report(writer.report)
        result.files = {fmt: str(staging / name) for fmt, name in names.items()}
    except (PuppetError, OSError) as err:
        result.fail(str(err) if isinstance(err, PuppetError) else _os_message(err))
    result.seconds = time.perf_counter() - start
    result.cpu_seconds = time.process_time() - cpu
    return result


def _os_message(err: OSError) -> str:
    where = f"{err.filename}: " if err.filename else ""
    return f"{where}{err.strerror or err}"
