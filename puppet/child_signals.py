"""Child processes that a terminal's Ctrl-C does not reach: their parent stops them.

A Ctrl-C in a terminal sends SIGINT to every process of the foreground group: the command and
every child it started. A spawned child (a fresh interpreter) would raise KeyboardInterrupt
wherever it is, even while still importing, and print a traceback. Children started inside
``children_deaf_to_ctrl_c()`` inherit SIGINT ignored (and blocked), through fork and exec,
for their whole life (Python keeps an inherited ignore): the parent alone sees the Ctrl-C and
stops them its own way (a stop word, a closed pipe). A Ctrl-C that reaches the parent while
the block runs is held and delivered to the parent's own handler when the block ends.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def children_deaf_to_ctrl_c() -> Iterator[None]:
    """Start child processes inside this block: they ignore SIGINT. (A handler can only be
    changed on the main thread; elsewhere the children get SIGINT blocked only.)"""
    previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    main = threading.current_thread() is threading.main_thread()
    previous_handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        yield
    finally:
        if main:  # None: a handler not set from Python; the default then
            signal.signal(signal.SIGINT, signal.SIG_DFL if previous_handler is None
                          else previous_handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, previous_mask)  # a held Ctrl-C arrives now
