"""Typed errors of the sound part; every message names the sound file at fault."""

from __future__ import annotations

from puppet.errors import PuppetError


class SoundError(PuppetError):
    """A sound file is missing, undecodable, empty, too long, or of a rate puppet refuses.

    path:   the sound file.
    reason: what is wrong with it, in words.
    """

    def __init__(self, path, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")
