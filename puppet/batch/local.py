"""The local engine: worker processes on this machine, one take per task.

The shared rig and precompute are pickled once by the driver and handed to each worker process
once, when it starts (never per take). Each worker has its own pipe: the driver sends it one
take, it answers with that take's result, so the driver always knows which take a worker holds.
Workers write into staging folders inside the output folder (the same file system) and the
driver renames finished files into place.

Limits and stops: a worker that dies (killed, out of memory, a crash in native code) is replaced
and the take it held is run again, up to ``retries`` more times. A take that runs past its time
limit (``task.take_timeout_s``) is stopped with its worker (SIGTERM, then SIGKILL after
``cancel.STOP_GRACE_S``), which is replaced; the take's row says "timed out". When the driver
stops (SIGINT, SIGTERM, an error) every worker is stopped the same way. Workers run with one
BLAS thread each (environment at start and ``one_blas_thread``), whoever started the batch, and
die with the driver (``PR_SET_PDEATHSIG``): a killed driver leaves no worker running on.
What a worker prints while it runs a take goes to that take's log (``task.run_take_logged``).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import pickle
import signal
import sys
import time
from collections.abc import Callable
from multiprocessing.connection import Connection, wait
from pathlib import Path

from puppet.batch.cancel import STOP_GRACE_S
from puppet.batch.plan import Job
from puppet.batch.row import TIMED_OUT, TakeResult
from puppet.batch.task import internal_error, run_take_logged, staging_folder, take_timeout_s
from puppet.child_signals import children_deaf_to_ctrl_c
from puppet.fast.blas import children_one_blas_thread

DEFAULT_RETRIES = 2  # tries after the first, of a take whose worker died under it
_PR_SET_PDEATHSIG = 1


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _die_with_parent(parent: int) -> None:
    """Ask the kernel for SIGTERM when the driver dies (Linux), then check it is still there."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # it died before the request: nobody to work for
        os._exit(0)


def _stop_on_sigterm(_signum, _frame) -> None:
    """SIGTERM (the driver stops the batch, or died): unwind the take (its video encoder is
    killed, its temporaries removed) and exit."""
    raise SystemExit(0)


def _worker_main(connection: Connection, blob: bytes, staging_root: str, parent: int) -> None:
    """A worker process: unpickle the shared state once, then run takes until told to stop."""
    signal.signal(signal.SIGTERM, _stop_on_sigterm)
    _die_with_parent(parent)
    from puppet.fast.blas import one_blas_thread

    shared = pickle.loads(blob)
    root = Path(staging_root)
    with one_blas_thread():
        while True:
            try:
                job = connection.recv()
            except EOFError:  # the driver is gone
                return
            if job is None:
                return
            try:
                result = run_take_logged(job, shared, staging_folder(root, job))
            except Exception as err:  # noqa: BLE001 - a bug in one take must not stop the others
                result = internal_error(job.take, err,
                                        worker=f"{os.uname().nodename}:{os.getpid()}")
            try:
                connection.send(result)
            except OSError:  # the driver is gone: nobody to tell
                return


class _Worker:
    """One worker process, its end of the pipe, the take it holds (None: idle) and the
    monotonic time by which that take must end."""

    def __init__(self, context, blob: bytes, staging_root: Path):
        self.connection, child = context.Pipe()
        self.process = context.Process(target=_worker_main,
                                       args=(child, blob, str(staging_root), os.getpid()),
                                       daemon=True)
        # a terminal's Ctrl-C is the driver's: it stops the workers; one BLAS thread each
        with children_deaf_to_ctrl_c(), children_one_blas_thread():
            self.process.start()
        child.close()
        self.job: Job | None = None
        self.deadline = float("inf")
        self.limit_s = float("inf")

    def give(self, job: Job, limit_s: float) -> None:
        self.job, self.limit_s = job, limit_s
        self.deadline = time.monotonic() + limit_s
        try:
            self.connection.send(job)
        except OSError:  # it died already: its sentinel says so and the take is given again
            pass

    def ask_to_stop(self, now: bool) -> None:
        """Ask the worker to exit: after its take (a stop word), or ``now`` (SIGTERM)."""
        try:
            self.connection.send(None)
        except OSError:  # already gone
            pass
        if now and self.process.is_alive():
            self.process.terminate()

    def reap(self, deadline: float) -> None:
        """Wait until ``deadline`` (monotonic) for the process to exit, then kill it."""
        self.process.join(timeout=max(0.0, deadline - time.monotonic()))
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.connection.close()


def _stop_all(workers: list[_Worker], now: bool) -> None:
    """Stop every worker: all asked at once, then each reaped (``now``: within STOP_GRACE_S)."""
    for worker in workers:
        worker.ask_to_stop(now)
    deadline = time.monotonic() + (STOP_GRACE_S if now else 30.0)
    for worker in workers:
        worker.reap(deadline)


class LocalEngine:
    """``workers`` processes (default: the machine's cores), each running one take at a time.
    retries: tries after the first of a take whose worker died; take_timeout: --take-timeout
    seconds (None: ``task.take_timeout_s``'s default scaled by each take's length)."""

    name = "local"

    def __init__(self, workers: int | None = None, *, retries: int = DEFAULT_RETRIES,
                 take_timeout: float | None = None):
        self.workers = int(workers) if workers else available_cores()
        self.retries = retries
        self.take_timeout = take_timeout

    def check(self) -> None:
        """Nothing to check before work starts: processes always start here."""

    def close(self) -> None:
        """Nothing outlives run()."""

    def run(self, jobs: list[Job], shared_blob: bytes, staging_root: Path,
            on_result: Callable[[Job, TakeResult], None]) -> None:
        """Run every job; call ``on_result(job, result)`` in the driver as each take ends."""
        context = multiprocessing.get_context("spawn")  # fresh interpreters: no inherited locks
        tries = {job.take: 0 for job in jobs}
        limits = {job.take: take_timeout_s(job.take, self.take_timeout) for job in jobs}
        todo = list(reversed(jobs))  # popped from the end: the given order

        def give_next(worker: _Worker) -> None:
            if todo:
                job = todo.pop()
                tries[job.take] += 1
                worker.give(job, limits[job.take])

        workers = [_Worker(context, shared_blob, staging_root)
                   for _ in range(min(self.workers, len(jobs)))]
        try:
            for worker in workers:
                give_next(worker)
            while any(w.job is not None for w in workers):
                busy = [w for w in workers if w.job is not None]
                wait_s = max(0.0, min(w.deadline for w in busy) - time.monotonic())
                ready = wait([w.connection for w in busy] + [w.process.sentinel for w in busy],
                             timeout=wait_s)
                for i, worker in enumerate(workers):
                    job = worker.job
                    if job is None:
                        continue
                    if worker.connection in ready:
                        try:
                            result = worker.connection.recv()
                        except (EOFError, OSError):  # died while answering
                            result = None
                        if result is not None:
                            worker.job = None
                            result.retries = tries[job.take] - 1
                            on_result(job, result)
                            give_next(worker)
                            continue
                    died = worker.process.sentinel in ready or not worker.process.is_alive()
                    if not died and time.monotonic() < worker.deadline:
                        continue
                    if died:
                        worker.process.join()
                        worker.connection.close()
                        if tries[job.take] <= self.retries:
                            todo.append(job)  # next in line again
                        else:
                            on_result(job, TakeResult.failed(
                                job.take, f"a worker process died under this take "
                                          f"{tries[job.take]} times (exit status "
                                          f"{worker.process.exitcode})",
                                retries=tries[job.take] - 1))
                    else:  # past its time limit: the worker is stopped and replaced
                        _stop_all([worker], now=True)
                        on_result(job, TakeResult.failed(
                            job.take, f"still running after {worker.limit_s:g} s "
                                      "(--take-timeout); its worker was stopped",
                            state=TIMED_OUT, retries=tries[job.take] - 1))
                    workers[i] = _Worker(context, shared_blob, staging_root)
                    give_next(workers[i])
        except BaseException:
            _stop_all(workers, now=True)
            raise
        _stop_all(workers, now=False)
