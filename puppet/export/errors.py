"""Typed errors of the export part; every message names the output file at fault."""

from __future__ import annotations

from puppet.errors import PuppetError


class ExportError(PuppetError):
    """An export cannot be written as asked.

    path:   the output file.
    reason: what is wrong (the argument, frame or joint at fault), in words.
    """

    def __init__(self, path, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")
