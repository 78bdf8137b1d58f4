"""The local engine: a pool of worker processes on this machine, one take per task.

The shared rig and precompute are pickled once by the driver and handed to each worker process
once, when it starts (never per take). Workers write into staging folders inside the output
folder (the same file system), and the driver renames finished files into place. A worker that
dies (killed, out of memory, a crash in native code) breaks the pool: the driver starts a new
one and submits again every take that had not finished, up to MAX_ATTEMPTS tries each.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from puppet.batch.plan import Job
from puppet.batch.task import Shared, TakeResult, run_take, staging_folder

MAX_ATTEMPTS = 3  # tries per take when workers die under it (a take that kills every worker fails)

_shared: Shared | None = None  # in each worker: the unpickled shared state


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _start_worker(blob: bytes) -> None:
    global _shared
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    _shared = pickle.loads(blob)


def _work(job: Job, staging_root: str) -> TakeResult:
    return run_take(job, _shared, staging_folder(Path(staging_root), job))


class LocalEngine:
    """A process pool of ``workers`` processes (default: the machine's cores)."""

    name = "local"

    def __init__(self, workers: int | None = None):
        self.workers = int(workers) if workers else available_cores()

    def check(self) -> None:
        """Nothing to check before work starts: a process pool always runs here."""

    def close(self) -> None:
        """Nothing outlives run(): each pool is shut down when its takes are done."""

    def run(self, jobs: list[Job], shared_blob: bytes, staging_root: Path,
            on_result: Callable[[Job, TakeResult], None]) -> None:
        """Run every job; call ``on_result(job, result)`` in the driver as each take ends."""
        attempts = {job.take: 0 for job in jobs}
        todo = list(jobs)
        context = multiprocessing.get_context("spawn")  # fresh interpreters: no inherited locks
        while todo:
            broken: list[Job] = []
            workers = min(self.workers, len(todo))
            with ProcessPoolExecutor(workers, mp_context=context, initializer=_start_worker,
                                     initargs=(shared_blob,)) as pool:
                futures: dict[Future, Job] = {}
                for job in todo:
                    attempts[job.take] += 1
                    futures[pool.submit(_work, job, str(staging_root))] = job
                pending = set(futures)
                while pending:
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for future in done:
                        job = futures[future]
                        try:
                            result = future.result()
                        except BrokenProcessPool:
                            broken.append(job)
                            continue
                        except Exception as err:  # noqa: BLE001 - a bug in one take must not stop the others
                            result = TakeResult(take=str(job.take),
                                                error=f"internal error: {type(err).__name__}: {err}")
                        result.attempts = attempts[job.take]
                        on_result(job, result)
            todo = []
            for job in broken:
                if attempts[job.take] < MAX_ATTEMPTS:
                    todo.append(job)
                else:
                    on_result(job, TakeResult(take=str(job.take), attempts=attempts[job.take],
                                              error=f"a worker process died under this take "
                                                    f"{attempts[job.take]} times"))
