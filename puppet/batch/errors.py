"""The batch part's typed error."""

from __future__ import annotations

from puppet.errors import PuppetError


class BatchError(PuppetError):
    """A batch that cannot start: no takes matched, an output folder that cannot be written, two
    takes that would write the same file, or an engine that cannot run (Ray missing, a cluster
    address that does not answer). Raised before any take is solved."""
