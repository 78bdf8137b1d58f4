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
import time
from dataclasses import dataclass, field
from pathlib import Path

from puppet.atomic import atomic_output
from puppet.batch.plan import Job
from puppet.batch.row import TakeResult
from puppet.errors import PuppetError
from puppet.loop import RigPrecompute
from puppet.rig import Rig

EXPORT_FORMATS = ("gltf", "usd", "pc2", "bvh")


@dataclass(frozen=True)
class Settings:
    """What every take is made with. formats: of plan.FORMATS; fps: frames per second of every
    output; up: PC2 up axis ('y' or 'z'); size: (width, height) pixels of the mp4; antialias:
    as ``puppet play --antialias`` (msaa by default, offline quality); space: the PC2's points'
    space as ``puppet export --space``; keys, keys_units: glTF key reduction as ``puppet export
    --keys/--keys-units`` (None: a key on every frame)."""

    formats: tuple[str, ...]
    fps: float = 30.0
    up: str = "y"
    space: str = "object"
    size: tuple[int, int] = (640, 480)
    antialias: str = "msaa"
    keys: float | None = None
    keys_units: float | None = None


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


def staging_folder(root: Path, job: Job) -> Path:
    """The worker's private folder for a take: ``root/<take name>.<pid>`` (a retry gets its own)."""
    folder = root / f"{job.name}.{os.getpid()}"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def run_take(job: Job, shared: Shared, staging: Path) -> TakeResult:
    """Solve ``job``'s take on the shared rig and write its outputs into ``staging``.

    A bad take (corrupt, foreign, empty) is a row in state failed with the reason, never an
    exception.
    """
    from puppet.export import ExportWriters, Outputs, export_take
    from puppet.export.run import take_frames
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
                                 precompute=precompute)
            result.frames = report.frames
            result.add_report(report)
        else:  # one solve of every frame: the video and every export from the same T
            frames = take_frames(rig, reader, settings.fps)
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
                    finally:
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
