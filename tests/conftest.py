"""Session-wide test setup: a private cache folder, and waiting for a condition.

Tests never write to the user's cache: ``PUPPET_CACHE`` points into a temporary folder for
the whole session (subprocesses started by tests inherit it).

Tests on a loaded 2-core machine must not depend on speed: instead of sleeping a fixed time
and then asserting a state, they wait for the state with ``wait_until`` and a generous timeout.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import TypeVar

import pytest

PATIENCE_S = 60.0
"""How long a test waits for a condition that a quiet machine meets in milliseconds."""

T = TypeVar("T")


def wait_until(predicate: Callable[[], T], timeout: float = PATIENCE_S, interval: float = 0.01,
               what: str = "condition") -> T:
    """Call ``predicate`` until it returns a true value (returned); AssertionError naming
    ``what`` when ``timeout`` seconds pass first."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not reached within {timeout} s")
        time.sleep(interval)


@pytest.fixture(name="wait_until")
def _wait_until_fixture():
    return wait_until


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory):
    """PUPPET_CACHE -> a temporary folder for the session (never the user's home cache)."""
    folder = tmp_path_factory.mktemp("puppet-cache")
    saved = os.environ.get("PUPPET_CACHE")
    os.environ["PUPPET_CACHE"] = str(folder)
    yield folder
    if saved is None:
        os.environ.pop("PUPPET_CACHE", None)
    else:
        os.environ["PUPPET_CACHE"] = saved
