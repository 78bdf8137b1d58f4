"""The one signal mechanism: SIGINT (Ctrl-C) and SIGTERM become a flag that loops poll.

``Signals`` is a context manager installed on the main thread (Python's rule; elsewhere it does
nothing and the caller's own stop path applies); the handlers it replaced are restored on exit.
The first signal sets ``stop`` (the loop ends after its frame and the session stops in order:
every output closed, the summary printed, exit 0). A second one, while stopping, sets ``hurry``
(waits are cut short) but never raises: every output is still closed. ``on_signal(name)``, when
given, runs inside the handler after the flag is set: ``puppet.batch.cancel`` raises its
``BatchCancelled`` from there, ``puppet.drive.perform`` only polls.

A signal that arrives before a command installs its own ``Signals`` (the imports, the first
second of start-up) is kept by ``early()``, installed as the command line starts: the session
sees it as its first signal and stops at once, before any servo is touched.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Signals:
    """SIGINT/SIGTERM as flags. ``stop``: a signal came; ``hurry``: two or more came;
    ``signal_name``: the first one's name ('SIGINT', 'SIGTERM'); ``count``: how many came
    (a number: bounded by construction). Calling the object returns ``stop`` (a loop's
    ``should_stop``)."""

    def __init__(self, on_signal: Callable[[str], None] | None = None) -> None:
        self.on_signal = on_signal
        self.count = 0
        self.signal_name: str | None = None
        self._saved: dict = {}

    @property
    def stop(self) -> bool:
        return self.count > 0

    @property
    def hurry(self) -> bool:
        return self.count > 1

    def __call__(self) -> bool:
        return self.count > 0

    def receive(self, name: str) -> None:
        """Take one signal by name (the handler's work; also a pending early signal's)."""
        self.count += 1
        if self.signal_name is None:
            self.signal_name = name
        if self.on_signal is not None:
            self.on_signal(name)

    def _handle(self, signum, _frame) -> None:
        self.receive(signal.Signals(signum).name)

    def __enter__(self) -> "Signals":
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._saved[sig] = signal.signal(sig, self._handle)
            pending = _early.take()
            if pending is not None:
                self.receive(pending)
        return self

    def reclaim(self) -> None:
        """Set the handlers again after a library replaced them (``ray.init`` sets its own)."""
        if self._saved and threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                signal.signal(sig, self._handle)

    def __exit__(self, *exc) -> None:
        saved, self._saved = self._saved, {}
        for sig, handler in saved.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)


class _Early:
    """Signals that came before a command's own ``Signals`` (see the module's docstring)."""

    def __init__(self) -> None:
        self.pending: str | None = None
        self.installed = False

    def _handle(self, signum, _frame) -> None:
        self.pending = self.pending or signal.Signals(signum).name

    def install(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                signal.signal(sig, self._handle)
            self.installed = True

    def take(self) -> str | None:
        """The pending signal's name (None if none came), forgotten once taken."""
        pending, self.pending = self.pending, None
        return pending

    def release(self) -> str | None:
        """Give the signals back to Python's defaults (a command without a session: Ctrl-C is
        KeyboardInterrupt there); returns a signal that came meanwhile (None if none)."""
        if self.installed:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            self.installed = False
        return self.take()


_early = _Early()


def early() -> None:
    """Keep a signal that arrives from now until a command's ``Signals`` takes over (the
    command line calls this first of all)."""
    _early.install()


def release_early() -> str | None:
    """For a command that runs no session: restore Python's handlers; the name of a signal
    that came meanwhile, or None."""
    return _early.release()
