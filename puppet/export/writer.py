"""The life of an export writer: write() per frame, then close() to finish or abort() to drop.

Every export writer (BVH, PC2, glTF, USD) has the same life: ``write()`` is refused after
``close()``/``abort()``, a second ``close()`` does nothing, and ``with`` closes it on the way out.
"""

from __future__ import annotations

from puppet.export.errors import ExportError


class ExportWriter:
    """Base of the streaming export writers.

    A subclass sets ``path`` (the output Path) and ``_closed = False`` and defines close()
    (finish the file; returns at once when ``_closed``, else sets it) and abort() (release
    the file unfinished; a failed export removes it).
    close_on_error: what ``with`` does when its block raises: True closes (every frame written
    stays readable), False aborts (a whole-document format: nothing partial is written).
    """

    close_on_error = True

    def _check_open(self) -> None:
        """Raise ExportError (naming the file) when write() comes after close() or abort()."""
        if self._closed:
            raise ExportError(self.path, "write() after close()")

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None or self.close_on_error:
            self.close()
        else:
            self.abort()


class CountPatchedWriter(ExportWriter):
    """A file written front to back whose header holds a count patched in place at close().

    A subclass opens ``_file`` (text or binary) and defines _count_field() -> (offset, data):
    where the count field starts (the file's tell() there, bytes from the start for a binary
    file) and its final contents (str for a text file, bytes for a binary one), same width as
    the placeholder written at the start.
    """

    def _count_field(self) -> tuple[int, str | bytes]:
        raise NotImplementedError

    def close(self) -> None:
        """Patch the count into the header and close. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            offset, data = self._count_field()
            self._file.seek(offset)
            self._file.write(data)
        finally:
            self._file.close()

    def abort(self) -> None:
        """Close the file as it is, without patching the header (a failed export removes it)."""
        if self._closed:
            return
        self._closed = True
        self._file.close()
