"""Typed errors raised by hw_sim (bad files name the file and line)."""

from __future__ import annotations


class HwSimError(Exception):
    """Base class for hw_sim errors."""


class _FileLineError(HwSimError, ValueError):
    """An error in a text input file, naming the file and (1-based) line."""

    def __init__(self, path: str, line: int | None, message: str):
        self.path = str(path)
        self.line = line
        self.message = message
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")

    def __reduce__(self):
        return (type(self), (self.path, self.line, self.message))


class MotionFileError(_FileLineError):
    """A keyframe or replay file that cannot be used as a motion source."""


class FaultFileError(_FileLineError):
    """A fault schedule file that cannot be parsed."""


class UnknownModelError(HwSimError, KeyError):
    """A servo model name that hw_sim does not simulate."""

    def __str__(self) -> str:
        return str(self.args[0])
