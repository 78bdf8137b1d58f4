"""The live session: a reading source, the one Pipeline and a set of outputs, with one start
order, one stop order and one rule for what a stop keeps (``puppet.session.session``); the one
signal mechanism (``puppet.session.signals``).

Importing the package imports nothing heavy: the command line sets its signal handlers from
``puppet.session.signals`` before numpy, the solver or the renderer load.
"""

__all__ = ["Session", "Signals"]


def __getattr__(name: str):
    if name == "Session":
        from puppet.session.session import Session

        return Session
    if name == "Signals":
        from puppet.session.signals import Signals

        return Signals
    raise AttributeError(f"module 'puppet.session' has no attribute {name!r}")
