"""The one root of puppet's library errors.

Every typed error of a part (``BusError``, ``RigError``, ``TakeError``, ``FastError``,
``RenderError``, ``ExportError`` ...) derives from ``PuppetError``; the command line catches it
once and prints ``Error: <message>`` with exit status 1. Nothing else reaches the user.
"""

from __future__ import annotations


class PuppetError(Exception):
    """Base of every error puppet's library raises on bad input or a failed device or file."""
