"""What every render pass shares: the GL objects it made, released once, also half-built."""

from __future__ import annotations

from contextlib import contextmanager


class GLPass:
    """A pass's context and the GL objects it owns. ``own(obj)`` records one as it is made;
    ``release()`` frees them all (newest first), once. Build inside ``with self.building():``
    so that a constructor that fails half-way releases what it had made before raising."""

    def __init__(self, ctx):
        self.ctx = ctx
        self._owned: list = []
        self.released = False

    def own(self, obj):
        """Record a GL object made by this pass; returns it."""
        self._owned.append(obj)
        return obj

    def disown(self, obj) -> None:
        """Release one owned object now (e.g. a buffer replaced by a bigger one)."""
        self._owned.remove(obj)
        obj.release()

    @contextmanager
    def building(self):
        try:
            yield
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        """Free every GL object of this pass (framebuffer 0 bound first: moderngl rebinds the
        current framebuffer after making one, and rebinding a deleted framebuffer would raise
        GL_INVALID_OPERATION in a shared context)."""
        if self.released:
            return
        self.released = True
        if self._owned:
            self.ctx.detect_framebuffer(0).use()
        for obj in reversed(self._owned):
            obj.release()
        self._owned.clear()
