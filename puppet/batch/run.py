"""Running a batch: check everything, find each take's rig, decide what to make, precompute
each rig once, run the takes, write, report.

    report = run_batch(["session/*.mcap"], "exports", formats=("gltf", "pc2"))
    print(report.table())

Order of work: formats, rates and sizes are checked, the takes expanded, the output folder
made and tried, output names planned, the engine named; then per take (in the driver) its
checksum and its rig (``plan.RigFinder``), and what its manifest says (``manifest.changes``:
why it is made, or that it is up to date). A dry run stops here and writes nothing. Then the
engine is started (Ray imported and reached) before each rig's precompute and any take: bad
input fails fast with a BatchError and nothing written. A take that fails (corrupt, foreign,
empty, its rig not found) is reported in its row and the others go on. A finished take's
outputs are renamed into place, then its manifest and its log are written.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from puppet.atomic import OutputError, atomic_output, check_folder_output, check_output
from puppet.batch.cancel import BatchCancelled, cancel_on_signals, held
from puppet.batch.errors import BatchError
from puppet.batch.local import LocalEngine
from puppet.batch.manifest import Made, changes, shaping_settings
from puppet.batch.manifest import read as read_manifest
from puppet.batch.manifest import write as write_manifest
from puppet.batch.plan import (DEFAULT_FORMATS, KINDS, Job, RigFinder, expand_takes,
                               parse_formats, plan_jobs, prepare_out)
from puppet.batch.ray_engine import RayEngine
from puppet.batch.row import (CANCELLED, DONE, FAILED, SKIPPED, STATES, TO_DO, UNFINISHED,
                              TakeResult)
from puppet.batch.staging import Staging, node_temp, remove_stale
from puppet.batch.task import Settings, Shared
from puppet.checksum import file_sha256
from puppet.errors import PuppetError
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
    dry_run: bool = False

    @property
    def failed(self) -> list[TakeResult]:
        """Rows of takes whose outputs were not written (failed, cancelled, timed out)."""
        return [r for r in self.rows if r.state in UNFINISHED]

    def counts(self) -> dict[str, int]:
        """{state: number of rows}, every state of row.STATES (and "to do" in a dry run)."""
        states = (TO_DO, *STATES) if self.dry_run else STATES
        return {state: sum(1 for r in self.rows if r.state == state) for state in states}

    def as_dict(self) -> dict:
        return {"engine": self.engine, "workers": self.workers, "out": self.out,
                "dry_run": self.dry_run,
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
        if self.dry_run:
            lines.append(f"dry run: {counts or 'no takes'}; nothing written in {self.out}")
            return "\n".join(line.rstrip() for line in lines)
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


def _check_space(space: str) -> None:
    from puppet.export.run import SPACES

    if space not in SPACES:
        raise BatchError(f"--space: must be one of {SPACES}, got {space!r}")


def _check_keys(keys, keys_units, formats) -> None:
    """--keys / --keys-units as ``puppet export`` takes them, for a batch's formats."""
    from puppet import limits

    if keys is None:
        if keys_units is not None:
            raise BatchError("--keys-units: needs --keys (the rotation tolerance, degrees)")
        return
    for option, value, bound in (("--keys", keys, limits.KEYS_DEG),
                                 ("--keys-units", keys_units, limits.KEYS_UNITS)):
        problem = None if value is None else bound.problem(value)
        if problem:
            raise BatchError(f"{option}: {problem}")
    if "gltf" not in formats:
        raise BatchError("--keys: reduces the glTF's keys: add gltf to --formats (BVH, USD and "
                         "PC2 keep every frame)")


def make_engine(engine: str, workers: int | None, address: str | None, *,
                retries: int | None = None, take_timeout: float | None = None):
    limits = dict(take_timeout=take_timeout)
    if retries is not None:
        limits["retries"] = retries
    if engine == "local":
        if address:
            raise BatchError("--address is for --engine ray")
        return LocalEngine(workers, **limits)
    if engine == "ray":
        return RayEngine(workers, address, **limits)
    raise BatchError(f"--engine: {engine!r} is not one of {ENGINES}")


def run_batch(takes: list[str], out: str | os.PathLike, *, rig: Rig | None = None,
              rig_inputs: list[Path] = (), formats=DEFAULT_FORMATS, fps=30.0, up: str = "y",
              space: str = "object", size=(640, 480), keys: float | None = None,
              keys_units: float | None = None,
              engine: str = "local", workers: int | None = None,
              address: str | None = None, resume: bool = False, dry_run: bool = False,
              force: bool = False, retries: int | None = None,
              take_timeout: float | None = None, on_start: Callable[[int], None] | None = None,
              on_result: Callable[[TakeResult], None] | None = None,
              base: Path | None = None, layers=None) -> BatchReport:
    """Solve and write every take; see the module docstring for the order of checks.

    takes: files, folders or glob patterns; out: the output folder (created); rig: the rig
    every take is solved on (--rig; a take of other servos is refused in its row), or None for
    each take's own (``plan.RigFinder``); rig_inputs: the rig's files (never overwritten).
    formats: of plan.FORMATS; fps, up, space, size, keys, keys_units: as ``puppet export`` /
    ``puppet play``.
    engine: 'local' or 'ray'; workers: processes (local) or CPUs of a local Ray (default: cores);
    address: a Ray cluster (None: a private instance). retries: tries after the first of a take
    whose worker died (default 2); take_timeout: seconds a take may run (default:
    ``task.take_timeout_s``'s, scaled by the take's length). resume: skip takes whose manifest says their outputs are up to date
    (``manifest.changes``; a redone take's row says why). dry_run: decide and report, per take,
    what would be done and why (rows "to do", "skipped", "failed"), writing nothing.
    on_start(number of takes to run) and on_result(row) as each ends drive the progress.
    base: the folder every take's outputs mirror below (a session's takes/ folder; default:
    each argument's, ``plan.expand_takes``). layers: a layered take's ``LayerOptions``
    (--mute/--solo/--punch, not strict: a take whose stack has none of them plays as recorded).
    SIGINT or SIGTERM (on the main thread) stops every worker, removes the staging folders and
    raises cancel.BatchCancelled with the report so far (takes not finished: cancelled).
    """
    start = time.perf_counter()
    formats = parse_formats(formats)
    fps, size = _check_settings(fps, up, size)
    _check_keys(keys, keys_units, formats)
    _check_space(space)
    if workers is not None and workers < 1:
        raise BatchError(f"--workers: {workers} must be >= 1")
    inputs = [Path(p) for p in rig_inputs]
    found = expand_takes(takes, base)
    paths = [take for take, _ in found]
    folder = check_folder_output(out, what="output folder") if dry_run else prepare_out(out)
    if not dry_run:
        remove_stale(folder)  # what a killed batch left (its lock is free): resume or not
    jobs = plan_jobs(found, folder, formats, inputs, force=force, dry_run=dry_run)
    runner = make_engine(engine, workers, address, retries=retries, take_timeout=take_timeout)
    report = BatchReport(engine=engine, workers=workers or getattr(runner, "workers", None),
                         out=str(folder), dry_run=dry_run)
    settings = Settings(formats=formats, fps=fps, up=up, space=space, size=size, keys=keys,
                        keys_units=keys_units, layers=layers)
    finder = RigFinder(rig)
    jobs, rows, made = _decide(jobs, finder, shaping_settings(settings), resume)
    inputs = _refuse_rig_files(jobs, rows, finder, inputs, force)
    todo = [job for job in jobs if rows[job.take].state == TO_DO]
    if dry_run:
        runner.close()
        report.rows = [rows[job.take] for job in jobs]
        report.seconds = time.perf_counter() - start
        return report
    refused = [job for job in jobs if rows[job.take].state == FAILED]
    received = None
    try:
        with cancel_on_signals() as received:
            try:
                _run(todo, refused, runner, finder, settings, folder, report, rows, made,
                     [*paths, *inputs], force, on_start, on_result)
            finally:
                runner.close()
    except KeyboardInterrupt as stop:  # BatchCancelled, or a Ctrl-C off the main thread
        name = (getattr(stop, "signal_name", None) or getattr(received, "signal_name", None)
                or "SIGINT")
        for job in todo:
            if rows[job.take].state == TO_DO:
                rows[job.take] = TakeResult.failed(job.take, f"cancelled by {name}",
                                                   state=CANCELLED)
                _write_log(job, rows[job.take], [*paths, *inputs], force)
        report.rows = [rows[job.take] for job in jobs]
        report.seconds = time.perf_counter() - start
        raise BatchCancelled(name, report) from None
    for job in todo:  # never reported by the engine (it stopped first): not run, not written
        if rows[job.take].state == TO_DO:
            rows[job.take].fail("not run: the batch stopped before this take", CANCELLED)
            rows[job.take].files = {}
    report.rows = [rows[job.take] for job in jobs]
    report.seconds = time.perf_counter() - start
    return report


def _refuse_rig_files(jobs: list[Job], rows: dict, finder: RigFinder, inputs: list[Path],
                      force: bool) -> list[Path]:
    """The command's inputs with every file of the rigs the takes found (a take's own rig: its
    character, buffers, images, calibration; ``puppet.rig.rig_file.loaded_files``); a take to
    do whose output is one of them fails here, before any work (``puppet.atomic``'s rule)."""
    from puppet.rig.rig_file import loaded_files

    inputs = list(dict.fromkeys([*inputs, *(path for take_rig in finder.rigs()
                                            for path in loaded_files(take_rig.rig))]))
    for job in jobs:
        if rows[job.take].state != TO_DO or not job.log.parent.is_dir():
            continue  # a dry run's folder yet to be made holds nothing to refuse
        try:
            for fmt, target in job.outputs.items():
                check_output(target, kind=KINDS[fmt], inputs=inputs, force=force)
            for target, what in ((job.log, "log file"), (job.manifest, "manifest")):
                check_output(target, kind="text", inputs=inputs, force=force, what=what)
        except OutputError as err:
            rows[job.take] = TakeResult.failed(job.take, str(err), log=str(job.log))
    return inputs


def _run(todo: list[Job], refused: list[Job], runner, finder: RigFinder, settings: Settings,
         folder: Path, report: BatchReport, rows: dict, made: dict, inputs: list[Path],
         force: bool, on_start, on_result) -> None:
    """Start the engine, precompute each rig once, run the takes, commit each as it ends."""
    if todo:
        runner.check()  # Ray imported and reached before the precompute and any take
        if isinstance(runner, RayEngine):
            remove_stale(node_temp())  # what killed batches' tasks left on this machine
    if on_start is not None and (todo or refused):
        on_start(len(todo) + len(refused))
    for job in refused:  # before running: its rig not found, or not fitting
        _write_log(job, rows[job.take], inputs, force)
        if on_result is not None:
            on_result(rows[job.take])
    if not todo:
        return
    shared = Shared(rigs=_precompute(finder, todo, report), settings=settings)
    blob = pickle.dumps(shared, protocol=pickle.HIGHEST_PROTOCOL)
    report.shared_bytes = len(blob)

    def finished(job: Job, result: TakeResult) -> None:
        with held():  # a take's files and manifest go into place whole, or not at all
            planned = rows[job.take]
            if result.error is None:
                _commit(job, result, made[job.take], inputs, force)
            else:
                result.files, result.data = {}, None
            if result.state == DONE and not result.reason:
                result.reason = planned.reason  # why it was made: new, or what changed
            _write_log(job, result, inputs, force)
            rows[job.take] = result
        if on_result is not None:
            on_result(result)

    stagings = [Staging(folder)]  # the workers' files (local), the driver's temporaries
    try:
        if isinstance(runner, RayEngine):
            stagings.append(Staging(node_temp()))  # the tasks' files on this machine
            runner.run(todo, shared, stagings[0].path.name, finished)
        else:
            runner.run(todo, blob, stagings[0].path, finished)
    finally:
        for staging in stagings:
            staging.remove()  # also what stopped or dead workers left


def _decide(jobs: list[Job], finder: RigFinder, shaping: dict, resume: bool
            ) -> tuple[list[Job], dict[Path, TakeResult], dict[Path, Made]]:
    """For every take, in the driver: its checksum and rig, and what its manifest says.

    Returns the jobs (each with its rig_key), a row per take (failed: unreadable take, its rig
    not found or not fitting; skipped: up to date with ``resume``; "to do": the reason says
    why, new or what changed) and what each take to do is made from (its manifest's record).
    """
    planned, rows, made = [], {}, {}
    for job in jobs:
        try:
            take_rig = finder.for_take(job.take)
            made[job.take] = Made(str(job.take), file_sha256(job.take), take_rig.rig.name,
                                  take_rig.file, take_rig.rig_sha256, take_rig.character, shaping)
        except (PuppetError, OSError) as err:
            rows[job.take] = TakeResult.failed(job.take, _message(err, job.take), log=str(job.log))
            planned.append(job)
            continue
        job = dataclasses.replace(job, rig_key=take_rig.key)
        planned.append(job)
        files = {fmt: str(path) for fmt, path in job.outputs.items()}
        why = changes(read_manifest(job.manifest), made[job.take], job.outputs)
        if resume and not why:
            rows[job.take] = TakeResult(take=str(job.take), state=SKIPPED, reason="up to date",
                                        files=files, log=str(job.log))
        else:
            rows[job.take] = TakeResult(take=str(job.take), state=TO_DO, files=files,
                                        reason="; ".join(why or ["up to date; made again "
                                                                 "(no --resume)"]))
    return planned, rows, made


def _precompute(finder: RigFinder, todo: list[Job], report: BatchReport) -> dict:
    """{rig key: (rig, precompute)} of every rig a take to do is solved on, each built once;
    their time and size are added to the report."""
    used = {job.rig_key for job in todo}
    rigs = {}
    for take_rig in finder.rigs():
        if take_rig.key in used:
            precompute = RigPrecompute.for_rig(take_rig.rig)
            report.precompute_s += precompute.seconds
            report.precompute_bytes += precompute.nbytes()
            rigs[take_rig.key] = (take_rig.rig, precompute)
    return rigs


def _message(err: Exception, take: Path) -> str:
    if isinstance(err, PuppetError):
        return str(err)
    return f"{err.filename or take}: {err.strerror or err}"


def _commit(job: Job, result: TakeResult, made: Made, inputs: list[Path], force: bool) -> None:
    """Put a finished take's files in place: rename from staging (local) or write the bytes a
    remote worker sent (Ray), each atomically, then its manifest; a failure here is the take's
    error (its manifest then describes none of the new files: the take is redone)."""
    try:
        for fmt, target in job.outputs.items():
            rule = dict(kind=KINDS[fmt], inputs=inputs, force=force)
            if result.data is not None:
                with atomic_output(target, **rule) as temporary:
                    temporary.write_bytes(result.data[fmt])
            else:
                check_output(target, **rule)  # again: the folder may have changed meanwhile
                os.replace(result.files[fmt], target)
            result.moved(result.files[fmt], str(target))
        result.files = {fmt: str(target) for fmt, target in job.outputs.items()}
        write_manifest(job.manifest, made, job.outputs, inputs=inputs, force=force)
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
