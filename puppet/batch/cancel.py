"""Cancelling a batch: SIGINT or SIGTERM to the driver stops every worker and ends the batch.

``run_batch`` runs inside ``cancel_on_signals()``: the first SIGINT (Ctrl-C) or SIGTERM raises
``BatchCancelled`` in the driver wherever it waits. The engine then stops its workers (local:
SIGTERM to each process, SIGKILL after ``STOP_GRACE_S``; Ray: every task cancelled, a private
instance shut down), the driver removes its staging folders and raises ``BatchCancelled`` again
with the report so far (done, cancelled and failed rows). Further signals while it cleans up
are ignored: the cleanup is bounded (``CANCEL_WITHIN_S`` in all). Inside ``held()`` (a finished
take's files renamed into place) a signal waits for the block's end, so a take's outputs are
put in place whole or not at all.

Workers never see the terminal's Ctrl-C (``puppet.child_signals``): the driver alone stops them.
Handlers are set only on the main thread (Python's rule); elsewhere Ctrl-C arrives as the
caller's KeyboardInterrupt and the engines stop their workers on it the same way.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from puppet.session.signals import Signals

STOP_GRACE_S = 5.0
"""How long a worker process has to exit after SIGTERM before it is killed (SIGKILL)."""

CANCEL_WITHIN_S = 30.0
"""Documented bound from the signal to the driver's exit, workers and staging gone (local:
STOP_GRACE_S at most; Ray: its tasks cancelled and a private instance shut down)."""



class BatchCancelled(KeyboardInterrupt):
    """The batch was stopped by ``signal_name`` ('SIGINT' or 'SIGTERM'). ``report``: the
    BatchReport so far (None while the engine is still stopping). A KeyboardInterrupt, so a
    caller's ``except KeyboardInterrupt`` still sees a Ctrl-C. ``exit_status``: 128 + the
    signal's number (130 for SIGINT, 143 for SIGTERM), as a shell reports a killed command."""

    def __init__(self, signal_name: str, report=None):
        super().__init__(signal_name)
        self.signal_name = signal_name
        self.report = report

    @property
    def exit_status(self) -> int:
        return 128 + int(signal.Signals[self.signal_name])


class _State:
    active = False       # inside cancel_on_signals (main thread)
    held = 0             # depth of held() blocks
    pending: str | None = None
    cancelled: str | None = None
    received = None      # the Received of the active block
    signals = None       # its puppet.session.signals.Signals


_state = _State()


def _on_signal(name: str) -> None:
    if _state.cancelled is not None:
        return  # already stopping: the cleanup is bounded
    if _state.held:
        _state.pending = _state.pending or name
        return
    _cancel(name)


def _cancel(name: str) -> None:
    _state.cancelled = name
    if _state.received is not None:
        _state.received.signal_name = name
    raise BatchCancelled(name)


class Received:
    """What ``cancel_on_signals`` yields: ``signal_name`` of the first signal, None until one
    came (a library that turned our BatchCancelled into a plain KeyboardInterrupt, as Ray's
    wait does, loses the name: it is kept here)."""

    signal_name: str | None = None


@contextmanager
def cancel_on_signals() -> Iterator[Received]:
    """SIGINT and SIGTERM raise BatchCancelled inside this block (main thread only)."""
    received = Received()
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    _state.held, _state.pending, _state.cancelled, _state.active = 0, None, None, True
    _state.received = received
    try:
        with Signals(on_signal=_on_signal) as signals:
            _state.signals = signals
            yield received
    finally:
        _state.held, _state.pending, _state.cancelled, _state.active = 0, None, None, False
        _state.received = _state.signals = None


def reclaim_signals() -> None:
    """Set our handlers again inside ``cancel_on_signals`` after a library replaced them (``ray.init``
    sets its own SIGTERM handler, and its core a C-level one)."""
    if _state.active and _state.signals is not None:
        _state.signals.reclaim()


@contextmanager
def held() -> Iterator[None]:
    """A signal that arrives inside this block takes effect at its end."""
    _state.held += 1
    try:
        yield
    finally:
        _state.held -= 1
        if not _state.held and _state.pending is not None and _state.cancelled is None:
            name, _state.pending = _state.pending, None
            _cancel(name)
