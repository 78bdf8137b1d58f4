"""The one signal mechanism (``puppet.session.signals.Signals``): a flag, never an exception;
the handlers it replaced are back when it ends."""

from __future__ import annotations

import os
import signal

from puppet.session.signals import Signals


def test_signals_flag_then_hurry_and_restore_the_handlers_they_replaced():
    seen = []

    def previous(signum, frame):
        seen.append(signum)

    old_int = signal.signal(signal.SIGINT, previous)
    old_term = signal.signal(signal.SIGTERM, previous)
    try:
        with Signals() as signals:
            assert not signals.stop and not signals.hurry
            os.kill(os.getpid(), signal.SIGTERM)  # handled before the next bytecode
            assert signals.stop and not signals.hurry and signals.signal_name == "SIGTERM"
            os.kill(os.getpid(), signal.SIGINT)   # a second one hurries, never raises
            assert signals.hurry and signals.count == 2 and signals.signal_name == "SIGTERM"
        assert seen == []
        assert signal.getsignal(signal.SIGINT) is previous
        assert signal.getsignal(signal.SIGTERM) is previous
        os.kill(os.getpid(), signal.SIGINT)  # the caller's own handler again
        assert seen == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
