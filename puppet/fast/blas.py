"""One BLAS thread for the precompute, so that its results do not depend on thread settings.

Multithreaded OpenBLAS splits the sums of a product or a factorization among its threads
differently for each thread count (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``,
``MKL_NUM_THREADS``, or the machine's cores when none is set). Measured on the built-in critter:
``Q = Mᵀ L M`` differs in its last bits (7e-17 relative) between one and two threads, the
factor's G, P2 and H by 1e-13; with 400 clusters and 40 extra weights the exported vertices of a
take then differ by up to 1.2e-4 of the bounding-box diagonal. ``one_blas_thread`` runs the
precompute (``FastModel``) and each factorization (``Solver``) with every BLAS and OpenMP library
of the process limited to one thread, and restores the caller's limits after: the process's own
setting is left alone. One thread is not slower here (bench/solver.py on 2 cores, 43k vertices:
precompute 0.15-0.67 s either way; a refactor 1.2 ms, against 48-100 ms on two busy threads).
"""

from __future__ import annotations

import contextlib
import os
import threading

import numpy  # noqa: F401  (loads numpy's BLAS before the libraries are listed)
import scipy.linalg  # noqa: F401  (scipy's own BLAS and LAPACK, which the factorization uses)
from threadpoolctl import ThreadpoolController

_lock = threading.Lock()
_state = {"controller": None, "depth": 0, "limiter": None}


@contextlib.contextmanager
def one_blas_thread():
    """Context manager (and decorator): BLAS and OpenMP at one thread inside, as before after.

    Safe across threads and nested: the first to enter sets the limit, the last to leave restores
    the limits found on entry. Costs about 10 µs (the libraries are listed once per process)."""
    with _lock:
        if _state["depth"] == 0:
            if _state["controller"] is None:
                _state["controller"] = ThreadpoolController()
            _state["limiter"] = _state["controller"].limit(limits=1)
        _state["depth"] += 1
    try:
        yield
    finally:
        with _lock:
            _state["depth"] -= 1
            if _state["depth"] == 0:
                _state["limiter"].restore_original_limits()
                _state["limiter"] = None


ONE_THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""The environment a child process needs to start with one BLAS and OpenMP thread: the libraries
read it when they load, before any code of the child could call ``one_blas_thread``."""


@contextlib.contextmanager
def children_one_blas_thread():
    """Child processes started inside this block get ONE_THREAD_ENV (the caller's own
    environment is restored after): batch workers, one per core, each on one thread."""
    saved = {name: os.environ.get(name) for name in ONE_THREAD_ENV}
    os.environ.update(ONE_THREAD_ENV)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
