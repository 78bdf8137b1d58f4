"""Typed errors of the renderer: a missing GL stack, bad input arrays, bad sink settings."""

from puppet.errors import PuppetError

#: System packages (Debian/Ubuntu names) that provide headless EGL with Mesa's llvmpipe.
EGL_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1-mesa-dri", "libgbm1")


class RenderError(PuppetError, RuntimeError):
    """The renderer cannot do what was asked (no EGL, GL limits exceeded, GL errors)."""


class RenderInputError(RenderError, ValueError):
    """An input array or option has the wrong shape, dtype, range or value; names the field."""


class SinkError(RenderError):
    """A frame sink cannot write: bad size, frame of the wrong shape, unwritable path."""
