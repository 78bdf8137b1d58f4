"""Typed errors of the take part; every message names the take file at fault."""

from __future__ import annotations

from puppet.errors import PuppetError


class TakeError(PuppetError):
    """A take file is missing, unreadable, or not a puppet take.

    path:   the take file.
    reason: what is wrong with it, in words.
    """

    def __init__(self, path, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class TakeRigMismatch(TakeError):
    """A take was recorded on a rig whose servos differ from the rig it is played on.

    take_ids, rig_ids: servo ids of the take and of the rig.
    """

    def __init__(self, path, reason: str, *, take_ids, rig_ids):
        self.take_ids = list(take_ids)
        self.rig_ids = list(rig_ids)
        super().__init__(path, reason)
