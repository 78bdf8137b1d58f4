"""Typed errors of the live view."""

from puppet.errors import PuppetError


class ViewError(PuppetError):
    """The live view cannot start or do what was asked (address in use, bad address, ...)."""
