"""Child processes that a terminal's Ctrl-C does not reach: their parent stops them.

A Ctrl-C in a terminal sends SIGINT to every process of the foreground group: the command and
every child it started. A spawned child (a fresh interpreter) would raise KeyboardInterrupt
wherever it is, even while still importing, and print a traceback. Children started inside
``sigint_blocked()`` inherit a signal mask with SIGINT blocked, through fork and exec, for
their whole life: the parent alone sees the Ctrl-C and stops them its own way (a stop word, a
closed pipe). A Ctrl-C that arrives in the parent meanwhile is delivered when the block ends.
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def sigint_blocked() -> Iterator[None]:
    """Block SIGINT in this thread while the block runs (start child processes in it)."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
