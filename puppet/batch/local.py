"""The local engine: worker processes on this machine, one take per task.

The shared rig and precompute are pickled once by the driver and handed to each worker process
once, when it starts (never per take). Each worker has its own pipe: the driver sends it one
take, it answers with that take's result, so the driver always knows which take a worker holds.
Workers write into staging folders inside the output folder (the same file system) and the
driver renames finished files into place. A worker that dies (killed, out of memory, a crash in
native code) is replaced and the one take it held is run again, up to MAX_ATTEMPTS tries.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
from collections.abc import Callable
from multiprocessing.connection import Connection, wait
from pathlib import Path

from puppet.batch.plan import Job
from puppet.batch.row import TakeResult
from puppet.batch.task import run_take, staging_folder
from puppet.child_signals import children_deaf_to_ctrl_c

MAX_ATTEMPTS = 3  # tries per take whose worker dies under it


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _worker_main(connection: Connection, blob: bytes, staging_root: str) -> None:
    """A worker process: unpickle the shared state once, then run takes until told to stop."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    shared = pickle.loads(blob)
    root = Path(staging_root)
    while True:
        try:
            job = connection.recv()
        except EOFError:  # the driver is gone
            return
        if job is None:
            return
        try:
            result = run_take(job, shared, staging_folder(root, job))
        except Exception as err:  # noqa: BLE001 - a bug in one take must not stop the others
            result = TakeResult.failed(job.take, f"internal error: {type(err).__name__}: {err}")
        try:
            connection.send(result)
        except OSError:  # the driver is gone: nobody to tell
            return


class _Worker:
    """One worker process, its end of the pipe, and the take it holds (None: idle)."""

    def __init__(self, context, blob: bytes, staging_root: Path):
        self.connection, child = context.Pipe()
        self.process = context.Process(target=_worker_main, args=(child, blob, str(staging_root)),
                                       daemon=True)
        with children_deaf_to_ctrl_c():  # a terminal's Ctrl-C is the driver's: it stops the workers
            self.process.start()
        child.close()
        self.job: Job | None = None

    def give(self, job: Job) -> None:
        self.job = job
        try:
            self.connection.send(job)
        except OSError:  # it died already: its sentinel says so and the take is given again
            pass

    def stop(self, now: bool = False) -> None:
        """Let the worker finish and exit (``now``: kill it, after a Ctrl-C or an error)."""
        try:
            self.connection.send(None)
        except OSError:  # already gone
            pass
        self.process.join(timeout=0 if now else 30)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.connection.close()


class LocalEngine:
    """``workers`` processes (default: the machine's cores), each running one take at a time."""

    name = "local"

    def __init__(self, workers: int | None = None):
        self.workers = int(workers) if workers else available_cores()

    def check(self) -> None:
        """Nothing to check before work starts: processes always start here."""

    def close(self) -> None:
        """Nothing outlives run()."""

    def run(self, jobs: list[Job], shared_blob: bytes, staging_root: Path,
            on_result: Callable[[Job, TakeResult], None]) -> None:
        """Run every job; call ``on_result(job, result)`` in the driver as each take ends."""
        context = multiprocessing.get_context("spawn")  # fresh interpreters: no inherited locks
        attempts = {job.take: 0 for job in jobs}
        todo = list(reversed(jobs))  # popped from the end: the given order
        workers = [_Worker(context, shared_blob, staging_root)
                   for _ in range(min(self.workers, len(jobs)))]
        try:
            for worker in workers:
                self._give_next(worker, todo, attempts)
            while any(w.job is not None for w in workers):
                busy = [w for w in workers if w.job is not None]
                ready = wait([w.connection for w in busy] + [w.process.sentinel for w in busy])
                for i, worker in enumerate(workers):
                    if worker.job is None:
                        continue
                    job = worker.job
                    if worker.connection in ready:
                        try:
                            result = worker.connection.recv()
                        except (EOFError, OSError):  # died while answering
                            result = None
                        if result is not None:
                            worker.job = None
                            result.retries = attempts[job.take] - 1
                            on_result(job, result)
                            self._give_next(worker, todo, attempts)
                            continue
                    if worker.process.sentinel in ready or not worker.process.is_alive():
                        worker.process.join()
                        worker.connection.close()
                        if attempts[job.take] < MAX_ATTEMPTS:
                            todo.append(job)  # next in line again
                        else:
                            on_result(job, TakeResult.failed(
                                job.take, f"a worker process died under this take "
                                          f"{attempts[job.take]} times (exit status "
                                          f"{worker.process.exitcode})",
                                retries=attempts[job.take] - 1))
                        workers[i] = _Worker(context, shared_blob, staging_root)
                        self._give_next(workers[i], todo, attempts)
        except BaseException:
            for worker in workers:
                worker.stop(now=True)
            raise
        for worker in workers:
            worker.stop()

    @staticmethod
    def _give_next(worker: _Worker, todo: list[Job], attempts: dict) -> None:
        if todo:
            job = todo.pop()
            attempts[job.take] += 1
            worker.give(job)
