"""Running a batch: check everything, precompute the rig once, run the takes, write, report.

    report = run_batch(["session/*.mcap"], "exports", rig=rig, formats=("gltf", "pc2"))
    print(report.table())

Order of work: formats, rates and sizes are checked, the takes expanded, the output folder
made and tried, output names planned and the engine started (Ray imported and reached) before
the rig's precompute and any take: bad input fails fast with a BatchError and nothing written.
A take that fails (corrupt, foreign, empty) is reported in its row and the others go on.
"""

from __future__ import annotations

import os
import pickle
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from puppet.atomic import OutputError, atomic_output, check_output
from puppet.batch.errors import BatchError
from puppet.batch.local import LocalEngine
from puppet.batch.plan import (DEFAULT_FORMATS, KINDS, Job, expand_takes, is_done, parse_formats,
                               plan_jobs, prepare_out)
from puppet.batch.ray_engine import RayEngine
from puppet.batch.row import SKIPPED, STATES, UNFINISHED, TakeResult
from puppet.batch.task import Settings, Shared
from puppet.loop import RigPrecompute
from puppet.rig import Rig

ENGINES = ("local", "ray")


@dataclass
class BatchReport:
    """What a batch did.

    rows: one TakeResult per take, in the order the takes were given (skipped ones included);
    out: the output folder; precompute_s / precompute_bytes: building the rig's FastModel and
    factorization once, and its pickled size; shared_bytes: everything sent once to each worker
    (rig + precompute + settings); seconds: wall time of the whole batch.
    """

    engine: str
    workers: int | None
    out: str = ""
    rows: list[TakeResult] = field(default_factory=list)
    precompute_s: float = 0.0
    precompute_bytes: int = 0
    shared_bytes: int = 0
    seconds: float = 0.0

    @property
    def failed(self) -> list[TakeResult]:
        """Rows of takes whose outputs were not written (failed, cancelled, timed out)."""
        return [r for r in self.rows if r.state in UNFINISHED]

    def counts(self) -> dict[str, int]:
        """{state: number of rows}, every state of row.STATES."""
        return {state: sum(1 for r in self.rows if r.state == state) for state in STATES}

    def as_dict(self) -> dict:
        return {"engine": self.engine, "workers": self.workers, "out": self.out,
                "precompute_s": round(self.precompute_s, 3),
                "precompute_bytes": self.precompute_bytes, "shared_bytes": self.shared_bytes,
                "seconds": round(self.seconds, 3), "counts": self.counts(),
                "takes": [r.as_dict() for r in self.rows]}

    def table(self) -> str:
        """The summary: one line per take (take, state, worker, cpu, wall, retries, outputs,
        reason), then the counts per state."""
        head = ("take", "state", "worker", "cpu s", "wall s", "retries", "outputs", "reason")
        folder = Path(self.out)
        body = []
        for r in self.rows:
            ran = r.state != SKIPPED and bool(r.worker)
            body.append((r.take, r.state, r.worker or "-",
                         f"{r.cpu_seconds:.2f}" if ran else "-",
                         f"{r.seconds:.2f}" if ran else "-", str(r.retries),
                         r.short_outputs(folder), r.reason))
        widths = [max(len(row[i]) for row in [head, *body]) for i in range(len(head) - 1)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(row[:-1], widths)) + "  " + row[-1]
                 for row in [head, *body]]
        counts = ", ".join(f"{n} {state}" for state, n in self.counts().items() if n)
        lines.append(f"{counts or 'no takes'} in {self.seconds:.1f} s on {self.engine} "
                     f"({self.workers or 'auto'} workers), outputs and logs in {self.out}; "
                     f"rig precompute {self.precompute_s:.2f} s, {self.precompute_bytes} bytes, "
                     f"shared once per worker ({self.shared_bytes} bytes with the rig)")
        return "\n".join(line.rstrip() for line in lines)


def _check_settings(fps, up: str, size) -> tuple[float, tuple[int, int]]:
    from puppet.export.run import check_fps

    fps_value = check_fps(fps)
    if up not in ("y", "z"):
        raise BatchError(f"--up: must be y or z, got {up!r}")
    width, height = (int(s) for s in size)
    if width < 2 or height < 2 or width % 2 or height % 2:
        raise BatchError(f"--size: {width}x{height}: width and height must be even numbers >= 2 "
                         "(the video is yuv420p)")
    return fps_value, (width, height)


def make_engine(engine: str, workers: int | None, address: str | None):
    if engine == "local":
        if address:
            raise BatchError("--address is for --engine ray")
        return LocalEngine(workers)
    if engine == "ray":
        return RayEngine(workers, address)
    raise BatchError(f"--engine: {engine!r} is not one of {ENGINES}")


def run_batch(takes: list[str], out: str | os.PathLike, *, rig: Rig, rig_inputs: list[Path] = (),
              default_rig: bool = False, formats=DEFAULT_FORMATS, fps=30.0, up: str = "y",
              size=(640, 480), engine: str = "local", workers: int | None = None,
              address: str | None = None, resume: bool = False, force: bool = False,
              on_start: Callable[[int], None] | None = None,
              on_result: Callable[[TakeResult], None] | None = None) -> BatchReport:
    """Solve and write every take; see the module docstring for the order of checks.

    takes: files, folders or glob patterns; out: the output folder (created); rig: the loaded
    rig every take is solved on; rig_inputs: the rig's files (never overwritten; --resume
    compares times with them); default_rig: no rig was named (takes must be the built-in's).
    formats: of plan.FORMATS; fps, up, size: as ``puppet export`` / ``puppet play``.
    engine: 'local' or 'ray'; workers: processes (local) or CPUs of a local Ray (default: cores);
    address: a Ray cluster. resume: skip takes whose outputs are all newer than their inputs.
    on_start(number of takes to run) and on_result(result) drive a progress bar.
    """
    start = time.perf_counter()
    formats = parse_formats(formats)
    fps, size = _check_settings(fps, up, size)
    if workers is not None and workers < 1:
        raise BatchError(f"--workers: {workers} must be >= 1")
    inputs = [Path(p) for p in rig_inputs]
    paths = expand_takes(takes)
    folder = prepare_out(out)
    jobs = plan_jobs(paths, folder, formats, inputs, force=force)
    runner = make_engine(engine, workers, address)
    report = BatchReport(engine=engine, workers=workers or getattr(runner, "workers", None),
                         out=str(folder))
    rows: dict[Path, TakeResult] = {}
    todo: list[Job] = []
    for job in jobs:
        if resume and is_done(job, inputs):
            rows[job.take] = TakeResult(take=str(job.take), state=SKIPPED, reason="up to date",
                                        files={f: str(p) for f, p in job.outputs.items()},
                                        log=str(job.log))
        else:
            todo.append(job)
    if todo:
        runner.check()  # Ray imported and reached before the precompute and any take
    try:
        if todo:
            precompute = RigPrecompute.for_rig(rig)
            report.precompute_s = precompute.seconds
            report.precompute_bytes = precompute.nbytes()
            shared = Shared(rig=rig, default_rig=default_rig, precompute=precompute,
                            settings=Settings(formats=formats, fps=fps, up=up, size=size))
            blob = pickle.dumps(shared, protocol=pickle.HIGHEST_PROTOCOL)
            report.shared_bytes = len(blob)
            if on_start is not None:
                on_start(len(todo))

            def finished(job: Job, result: TakeResult) -> None:
                if result.error is None:
                    _commit(job, result, [*paths, *inputs], force)
                else:
                    result.files, result.data = {}, None
                _write_log(job, result, [*paths, *inputs], force)
                rows[job.take] = result
                if on_result is not None:
                    on_result(result)

            staging_root = folder / f".puppet-batch.{os.getpid()}.partial"
            try:
                if isinstance(runner, RayEngine):
                    runner.run(todo, shared, finished)
                else:
                    staging_root.mkdir(exist_ok=True)
                    runner.run(todo, blob, staging_root, finished)
            finally:
                shutil.rmtree(staging_root, ignore_errors=True)  # what dead workers left
    finally:
        runner.close()
    report.rows = [rows[job.take] for job in jobs]
    report.seconds = time.perf_counter() - start
    return report


def _commit(job: Job, result: TakeResult, inputs: list[Path], force: bool) -> None:
    """Put a finished take's files in place: rename from staging (local) or write the bytes a
    remote worker sent (Ray), each atomically; a failure here is the take's error."""
    try:
        for fmt, target in job.outputs.items():
            rule = dict(kind=KINDS[fmt], inputs=inputs, force=force)
            if result.data is not None:
                with atomic_output(target, **rule) as temporary:
                    temporary.write_bytes(result.data[fmt])
            else:
                check_output(target, **rule)  # again: the folder may have changed meanwhile
                os.replace(result.files[fmt], target)
        result.files = {fmt: str(target) for fmt, target in job.outputs.items()}
    except OutputError as err:
        result.fail(str(err))
    except OSError as err:
        result.fail(f"{err.filename or job.take}: cannot write the output: {err.strerror or err}")
    if result.error is not None:
        result.files = {}
    result.data = None


def _write_log(job: Job, result: TakeResult, inputs: list[Path], force: bool) -> None:
    """Write the take's log file (atomically); a log that cannot be written is a warning in the
    row, never the take's failure (its outputs are in place)."""
    try:
        with atomic_output(job.log, kind="text", inputs=inputs, force=force,
                           what="log file") as temporary:
            temporary.write_text(result.log_text(), encoding="utf-8")
        result.log = str(job.log)
    except OutputError as err:
        result.warnings.append(f"log not written: {err}")
    except OSError as err:
        result.warnings.append(f"log not written: {err.filename or job.log}: "
                               f"{err.strerror or err}")
