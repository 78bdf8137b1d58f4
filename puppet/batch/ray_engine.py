"""The Ray engine: one take per Ray task, on this machine or on a running Ray cluster.

Ray is an optional dependency (``pip install 'puppet[ray]'``). The shared rig and precompute
are put once in Ray's object store (each node fetches them once; tasks on a node map the same
copy). Where outputs go: every task writes into a temporary folder on its own node and returns
the finished files' bytes; the driver writes them into ``--out`` (atomically, through
``puppet.atomic``). The take's bytes travel with its task (a take is small: about 6 kB per second
of a 15-servo puppet at 30 Hz). So nodes need no shared file system, ``--resume`` and the summary only look
at the driver's folder, and a task that dies (its node or worker lost) leaves nothing behind:
Ray runs it again (``max_retries``) and only a complete result is ever written.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import socket
import tempfile
from collections.abc import Callable
from pathlib import Path

from puppet.batch.errors import BatchError
from puppet.batch.plan import Job
from puppet.batch.row import TakeResult
from puppet.batch.task import Shared, run_take, staging_folder

INSTALL_HINT = "pip install 'puppet[ray]'"
MAX_RETRIES = 3        # Ray re-runs a task whose worker process or node died
CONNECT_TIMEOUT_S = 10.0


def import_ray():
    """The ray module; BatchError naming the extra to install when it is missing."""
    try:
        import ray
    except ImportError:
        raise BatchError(f"--engine ray: Ray is not installed; install it with {INSTALL_HINT}"
                         ) from None
    return ray


def _host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of 'host:port' or 'ray://host:port'; None for 'auto' / 'local'."""
    text = address.split("://", 1)[-1]
    if address in ("auto", "local") or ":" not in text:
        return None
    host, _, port = text.rpartition(":")
    try:
        return host.strip("[]"), int(port)
    except ValueError:
        raise BatchError(f"--address {address}: expected host:port (e.g. 10.0.0.5:6379) or "
                         "ray://host:10001") from None


def _ray_task(job: Job, take_bytes: bytes, shared: Shared) -> TakeResult:
    """Run in a Ray worker: the take's bytes arrive with the task (no shared file system needed);
    solve and write into a node-local folder, return the files' bytes."""
    root = Path(tempfile.mkdtemp(prefix="puppet-batch-"))
    try:
        local_take = root / job.take.name
        local_take.write_bytes(take_bytes)
        local_job = dataclasses.replace(job, take=local_take)
        result = run_take(local_job, shared, staging_folder(root, local_job))
        result.take = str(job.take)
        # name the user's take, not this node's copy
        result.reason = result.reason.replace(str(local_take), str(job.take))
        result.warnings = [w.replace(str(local_take), str(job.take)) for w in result.warnings]
        if result.error is None:
            result.data = {fmt: Path(path).read_bytes() for fmt, path in result.files.items()}
        return result
    finally:
        shutil.rmtree(root, ignore_errors=True)


class RayEngine:
    """Ray tasks. address: None starts a local Ray instance of ``workers`` CPUs (default: the
    machine's cores); otherwise a running cluster ('host:6379', 'ray://host:10001' or 'auto').
    An already initialised Ray (``ray.init`` by the caller) is used as it is and left running."""

    name = "ray"

    def __init__(self, workers: int | None = None, address: str | None = None):
        self.workers = workers
        self.address = address
        self._started = False

    def check(self) -> None:
        """Import Ray and connect (or start it); BatchError before any work otherwise."""
        ray = import_ray()
        if ray.is_initialized():
            return
        if self.address:
            target = _host_port(self.address)
            if target is not None:
                try:
                    socket.create_connection(target, timeout=CONNECT_TIMEOUT_S).close()
                except OSError as err:
                    raise BatchError(f"--address {self.address}: no Ray cluster answers there "
                                     f"({err.strerror or err})") from None
        if not self.address:
            # A local instance of our own, on loopback, for this batch only: no token needed
            # between its processes (a stale token file of another session must not fail tasks).
            os.environ.setdefault("RAY_AUTH_MODE", "disabled")
        try:
            ray.init(address=self.address, num_cpus=None if self.address else self.workers,
                     include_dashboard=False, log_to_driver=False,
                     configure_logging=False)
        except (ConnectionError, RuntimeError, ValueError) as err:
            where = f"--address {self.address}" if self.address else "--engine ray"
            raise BatchError(f"{where}: cannot start or reach Ray: {err}") from None
        self._started = True

    def close(self) -> None:
        if self._started:
            import_ray().shutdown()
            self._started = False

    def run(self, jobs: list[Job], shared: Shared, on_result: Callable[[Job, TakeResult], None]
            ) -> float:
        """Run every job; ``on_result(job, result)`` in the driver as each ends (data attached).
        Returns the seconds it took to put the shared state in the object store."""
        import time

        ray = import_ray()
        start = time.perf_counter()
        shared_ref = ray.put(shared)  # once; every task gets this reference
        put_s = time.perf_counter() - start
        task = ray.remote(num_cpus=1, max_retries=MAX_RETRIES)(_ray_task)
        futures = {}
        for job in jobs:
            try:
                take_bytes = job.take.read_bytes()
            except OSError as err:
                on_result(job, TakeResult.failed(job.take, f"{job.take}: cannot read the take: "
                                                           f"{err.strerror or err}"))
                continue
            futures[task.remote(job, take_bytes, shared_ref)] = job
        pending = list(futures)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            job = futures[done[0]]
            try:
                result = ray.get(done[0])
            except ray.exceptions.RayError as err:  # retries exhausted: worker or node lost
                result = TakeResult.failed(job.take, f"Ray task failed: {err}")
            on_result(job, result)
        return put_s
