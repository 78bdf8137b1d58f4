"""The Ray engine: one take per Ray task, on a private Ray instance or on a running cluster.

Ray is an optional dependency (``pip install 'puppet[ray]'``). Where it runs:

- no ``--address``: a private Ray instance of ``workers`` CPUs (default: the cores) is started
  for this batch and shut down at its end; a cluster already running on the machine is never
  joined (``ray.init(address="local")``).
- ``--address auto``: the cluster running on this machine (``ray start --head``).
- ``--address host:6379`` or ``ray://host:10001``: that cluster. Before Ray is asked to
  connect, the address must answer as a Ray head does (gRPC: an HTTP/2 server preface) within
  ``CONNECT_TIMEOUT_S`` (``$PUPPET_RAY_CONNECT_TIMEOUT_S`` sets another); anything else
  (nothing listening, a port of another program) is a BatchError naming the address, never
  a hang of Ray's own reconnection loop.

The shared rig and precompute are put once in Ray's object store (each node fetches them once;
tasks on a node map the same copy). Every task writes into a staging folder on its own node
(``staging.node_temp()``, named as the driver's) and returns the finished files' bytes; the
driver writes them into ``--out`` (atomically, through ``puppet.atomic``). The take's bytes
travel with its task (a take is small: about 35 kB per second of a 15-servo puppet read at
about 240 Hz).
So nodes need no shared file system, ``--resume`` and the summary only look at the driver's
folder, and a task that dies leaves nothing at a final name.

Limits and stops: at most as many tasks as the instance's CPUs (or ``workers``) are submitted at
once, so a task's time limit (``task.take_timeout_s``) counts from about its start; a task past
it is cancelled with force (its worker process killed) and its row says "timed out". A task
whose worker or node died is submitted again by the driver (Ray's own ``max_retries`` is 0, so
every try is counted in the row) up to ``retries`` times. When the driver stops (SIGINT,
SIGTERM, an error) every running task is cancelled with force and a private instance is shut
down with all its processes. Each task's output on stdout and stderr (Ray's worker lines, a
library's warnings: ``task.run_take_logged``) and the messages Ray's raylets push to the driver
while it runs are kept, colour codes removed, in its row's log lines (the take's log file):
nothing of Ray's reaches the terminal.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import socket
import sys
import time
import warnings
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

from puppet.batch.cancel import reclaim_signals
from puppet.batch.errors import BatchError
from puppet.batch.plan import Job
from puppet.batch.row import TIMED_OUT, TakeResult, plain
from puppet.batch.staging import node_temp
from puppet.batch.task import (TRACEBACK_LINES, Shared, internal_error, run_take_logged,
                               staging_folder, take_timeout_s)
from puppet.fast.blas import children_one_blas_thread

INSTALL_HINT = "pip install 'puppet[ray]'"
DEFAULT_RETRIES = 2      # tries after the first, of a task whose worker process or node died
CONNECT_TIMEOUT_S = 10.0
"""An --address must answer as a Ray head within this time (documented: about 10 s)."""
CONNECT_TIMEOUT_ENV = "PUPPET_RAY_CONNECT_TIMEOUT_S"
"""The environment setting that replaces CONNECT_TIMEOUT_S (seconds; tests of the mechanism)."""
POLL_S = 0.5             # the driver wakes at least this often (signals, time limits)
_RETRIED = ("WorkerCrashedError", "NodeDiedError", "OutOfMemoryError", "LocalRayletDiedError",
            "ObjectLostError", "OwnerDiedError")
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"


def import_ray():
    """The ray module; BatchError naming the extra to install when it is missing."""
    try:
        import ray
    except ImportError:
        raise BatchError(f"--engine ray: Ray is not installed; install it with {INSTALL_HINT}"
                         ) from None
    return ray


def _host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of 'host:port' or 'ray://host:port'; None for 'auto'."""
    text = address.split("://", 1)[-1]
    if address == "auto":
        return None
    host, _, port = text.rpartition(":")
    try:
        if not host:
            raise ValueError
        return host.strip("[]"), int(port)
    except ValueError:
        raise BatchError(f"--address {address}: expected host:port (e.g. 10.0.0.5:6379), "
                         "ray://host:10001 or auto") from None


def connect_timeout_s() -> float:
    """CONNECT_TIMEOUT_S, or ``$PUPPET_RAY_CONNECT_TIMEOUT_S`` when set (BatchError naming it
    when not a number of seconds)."""
    from puppet.limits import SECONDS, from_environment

    try:
        return from_environment(CONNECT_TIMEOUT_ENV, CONNECT_TIMEOUT_S, SECONDS)
    except ValueError as err:
        raise BatchError(str(err)) from None


def check_ray_head(address: str, timeout_s: float | None = None) -> None:
    """BatchError naming ``address`` unless a gRPC server (a Ray head's GCS or Ray Client
    server) answers there within ``timeout_s`` (None: ``connect_timeout_s()``): it must accept,
    and answer the HTTP/2 client preface with its SETTINGS frame."""
    target = _host_port(address)
    if target is None:
        return
    if timeout_s is None:
        timeout_s = connect_timeout_s()
    deadline = time.monotonic() + timeout_s
    try:
        with socket.create_connection(target, timeout=timeout_s) as sock:
            sock.sendall(_HTTP2_PREFACE)
            header = b""
            while len(header) < 9:
                sock.settimeout(max(0.01, deadline - time.monotonic()))
                chunk = sock.recv(9 - len(header))
                if not chunk:
                    raise BatchError(f"--address {address}: not a Ray head (it closed the "
                                     "connection without a gRPC answer)")
                header += chunk
    except TimeoutError:
        raise BatchError(f"--address {address}: not a Ray head (no gRPC answer within "
                         f"{timeout_s:g} s)") from None
    except OSError as err:
        raise BatchError(f"--address {address}: no Ray head answers there "
                         f"({err.strerror or err})") from None
    if header[3] != 0x4:  # a SETTINGS frame comes first from every HTTP/2 server
        raise BatchError(f"--address {address}: not a Ray head (it answered, but not gRPC)")


def _ray_task(job: Job, take_bytes: bytes, shared: Shared, staging_name: str) -> TakeResult:
    """Run in a Ray worker: the take's bytes arrive with the task (no shared file system needed);
    solve and write into a folder on this node, return the files' bytes and the task's lines."""
    from puppet.fast.blas import one_blas_thread

    folder = staging_folder(node_temp() / staging_name, job)
    try:
        local_take = folder / job.take.name
        local_take.write_bytes(take_bytes)
        local_job = dataclasses.replace(job, take=local_take)
        try:
            with one_blas_thread():
                result = run_take_logged(local_job, shared, folder)
        except Exception as err:  # noqa: BLE001 - its row carries the worker's own error
            result = internal_error(job.take, err, worker=f"{os.uname().nodename}:{os.getpid()}")
        result.take = str(job.take)
        # name the user's take, not this node's copy
        result.reason = result.reason.replace(str(local_take), str(job.take))
        result.warnings = [w.replace(str(local_take), str(job.take)) for w in result.warnings]
        if result.error is None:
            result.data = {fmt: Path(path).read_bytes() for fmt, path in result.files.items()}
        return result
    finally:
        shutil.rmtree(folder, ignore_errors=True)


class RayEngine:
    """Ray tasks. address: None starts a private Ray instance of ``workers`` CPUs (default: the
    machine's cores); 'auto' or 'host:6379' / 'ray://host:10001': a running cluster (there,
    ``workers`` bounds the tasks at once). An already initialised Ray (``ray.init`` by the
    caller) is used as it is and left running. retries, take_timeout: as LocalEngine."""

    name = "ray"

    def __init__(self, workers: int | None = None, address: str | None = None, *,
                 retries: int = DEFAULT_RETRIES, take_timeout: float | None = None):
        self.workers = workers
        self.address = address
        self.retries = retries
        self.take_timeout = take_timeout
        self._started = False

    def check(self) -> None:
        """Import Ray and connect (or start a private instance); BatchError before any work."""
        ray = import_ray()
        if ray.is_initialized():
            return
        if self.address:
            check_ray_head(self.address)
        private = not self.address
        if private:
            # our own instance, on loopback, for this batch only: no token between its
            # processes (a stale token file of another session must not fail tasks), and one
            # BLAS thread per worker process (they inherit this environment)
            os.environ.setdefault("RAY_AUTH_MODE", "disabled")
        self._started = True  # from here on close() shuts down whatever init started
        try:
            with _quiet_ray(), children_one_blas_thread():
                ray.init(address="local" if private else self.address,
                         num_cpus=self.workers if private else None,
                         include_dashboard=False, log_to_driver=False, configure_logging=False)
        except (ConnectionError, RuntimeError, ValueError) as err:
            self.close()
            where = f"--address {self.address}" if self.address else "--engine ray"
            raise BatchError(f"{where}: cannot start or reach Ray: {err}") from None
        reclaim_signals()  # Ray's core set its own SIGTERM handler: a batch stops our way
        self._hear_raylet()

    def _hear_raylet(self) -> None:
        """Ray's driver prints the messages its raylets push (a worker died, out of memory) on
        stdout from a thread of its own, coloured; they are kept for the rows of the takes that
        were running instead (``ray._private.worker.print_to_stdstream``: no public hook)."""
        import ray._private.worker as ray_worker

        self._lines: list[str] = []
        self._printer = getattr(ray_worker, "print_to_stdstream", None)
        if self._printer is not None:
            ray_worker.print_to_stdstream = lambda data, **_: self._lines.extend(
                f"({data.get('pid', 'ray')}) {line}" for line in data.get("lines", ()))

    def close(self) -> None:
        """Shut down what check() started (a private instance stops with every process)."""
        if getattr(self, "_printer", None) is not None:
            import ray._private.worker as ray_worker

            ray_worker.print_to_stdstream, self._printer = self._printer, None
        if self._started:
            self._started = False
            with _quiet_ray():
                import_ray().shutdown()

    def slots(self) -> int:
        """Tasks submitted at once: ``workers``, else the instance's CPUs."""
        if self.workers:
            return int(self.workers)
        cpus = import_ray().cluster_resources().get("CPU", 1)
        return max(1, int(cpus))

    def run(self, jobs: list[Job], shared: Shared, staging_name: str,
            on_result: Callable[[Job, TakeResult], None]) -> float:
        """Run every job; ``on_result(job, result)`` in the driver as each ends (data attached).
        Returns the seconds it took to put the shared state in the object store."""
        ray = import_ray()
        start = time.perf_counter()
        shared_ref = ray.put(shared)  # once; every task gets this reference
        put_s = time.perf_counter() - start
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_task)
        todo = list(reversed(jobs))
        tries = {job.take: 0 for job in jobs}
        limits = {job.take: take_timeout_s(job.take, self.take_timeout) for job in jobs}
        running: dict = {}  # ObjectRef -> (job, deadline)
        notes: dict[Path, list[str]] = {}  # Ray's lines heard while a take ran
        slots = self.slots()
        try:
            while todo or running:
                while todo and len(running) < slots:
                    job = todo.pop()
                    try:
                        take_bytes = job.take.read_bytes()
                    except OSError as err:
                        on_result(job, TakeResult.failed(job.take, f"{job.take}: cannot read "
                                                                   f"the take: {err.strerror or err}"))
                        continue
                    tries[job.take] += 1
                    ref = task.remote(job, take_bytes, shared_ref, staging_name)
                    running[ref] = (job, time.monotonic() + limits[job.take])
                if not running:
                    continue
                soonest = min(deadline for _, deadline in running.values())
                wait_s = min(POLL_S, max(0.0, soonest - time.monotonic()))
                done, _ = ray.wait(list(running), num_returns=1, timeout=wait_s)
                heard = self._heard()
                for job, _ in running.values():  # Ray's lines go to the takes then running
                    notes.setdefault(job.take, []).extend(heard)
                for ref in done:
                    job, _ = running.pop(ref)
                    result = self._result(ray, ref, job, tries[job.take])
                    if result is None:
                        todo.append(job)  # its worker or node died: next in line again
                    else:
                        result.log_lines[:0] = notes.pop(job.take, [])
                        on_result(job, result)
                now = time.monotonic()
                for ref, (job, deadline) in list(running.items()):
                    if now >= deadline:
                        del running[ref]
                        ray.cancel(ref, force=True)
                        on_result(job, TakeResult.failed(
                            job.take, f"still running after {limits[job.take]:g} s "
                                      "(--take-timeout); its Ray task was cancelled with force",
                            state=TIMED_OUT, retries=tries[job.take] - 1,
                            log_lines=notes.pop(job.take, [])))
        except BaseException:
            for ref in running:
                try:
                    ray.cancel(ref, force=True)
                except Exception as err:  # noqa: BLE001 - stopping anyway: said, the instance goes next
                    print(f"warning: a Ray task could not be cancelled: {err}", file=sys.stderr)
            raise
        return put_s

    def _heard(self) -> list[str]:
        """Ray's lines heard since the last call, colour codes removed."""
        lines = getattr(self, "_lines", [])
        heard = [plain(line) for line in lines[:len(lines)]]
        del lines[:len(heard)]
        return heard

    def _result(self, ray, ref, job: Job, tries: int) -> TakeResult | None:
        """The finished task's row; None when it should run again (its worker or node died)."""
        try:
            result = ray.get(ref)
        except ray.exceptions.RayError as err:
            if type(err).__name__ in _RETRIED and tries <= self.retries:
                return None
            return failed_row(err, job.take, tries)
        result.retries = tries - 1
        return result


def failed_row(err, take, tries: int) -> TakeResult:
    """The row of a take whose Ray task raised ``err`` (a RayError) after ``tries`` tries: a
    RayTaskError carries the task's own exception (its ``cause``) and the worker's traceback as
    text (its ``traceback_str``): the reason names the exception and where it was raised, the
    log holds the end of that traceback; any other RayError: its last line, and its lines."""
    what = "its Ray worker or node died" if type(err).__name__ in _RETRIED else \
        "the Ray task failed"
    cause = getattr(err, "cause", None)  # a RayTaskError: the task's own exception
    if isinstance(cause, BaseException):
        # its traceback stayed in the worker: Ray sends it as text
        # (what ray.get raises: the cause's class and RayTaskError both; its text is the
        # worker's traceback under a first line "ray::_ray_task() (pid=..., ip=...)")
        text = plain(getattr(err, "traceback_str", None) or str(err))
        result = internal_error(take, cause, traceback_text=text, worker=_worker_of(text))
        result.reason = f"{what} ({tries} tries): {result.reason}"
    else:
        lines = [plain(line) for line in str(err).strip().splitlines() if line.strip()]
        last = lines[-1] if lines else type(err).__name__
        result = TakeResult.failed(take, f"{what} ({tries} tries): {type(err).__name__}: {last}")
        for line in lines[-TRACEBACK_LINES:]:
            result.add_log(line)
    result.retries = tries - 1
    return result


def _worker_of(text: str) -> str:
    """'ip:pid' of the Ray worker a RayTaskError's text names ('' when it does not)."""
    import re

    found = re.search(r"\(pid=(\d+), ip=([^)\s]+)\)", text)
    return f"{found[2]}:{found[1]}" if found else ""


@contextmanager
def _quiet_ray():
    """Ray's own log records and Python warnings below errors are not shown on the terminal
    while it starts and stops (its processes log into its session folder)."""
    logger = logging.getLogger("ray")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.setLevel(level)
