"""Typed bus errors. Each carries the servo ids and the instruction it concerns."""

from __future__ import annotations

from collections.abc import Iterable

from puppet.errors import PuppetError


class BusError(PuppetError):
    """Base of every error raised by ``puppet.bus``."""


class PortError(BusError):
    """The serial port could not be opened, or was lost (USB unplug).

    port:  the port name, e.g. '/dev/ttyUSB0'.
    cause: the underlying exception (SerialException, OSError, termios.error) or None;
           ``cause_text`` its repr (all that survives pickling).
    """

    def __init__(self, port: str, reason: str, cause: BaseException | None = None):
        self.port = port
        self.reason = reason
        self.cause = cause
        self.cause_text = None if cause is None else repr(cause)
        detail = f" ({type(cause).__name__}: {cause})" if cause is not None else ""
        super().__init__(f"port {port}: {reason}{detail}")

    def __reduce__(self):
        # The cause travels as text: OS-level exceptions do not all pickle.
        return (_port_error_from_text, (self.port, self.reason, repr(self.cause) if self.cause else None))


def _port_error_from_text(port: str, reason: str, cause_text: str | None) -> PortError:
    error = PortError(port, reason)
    error.cause_text = cause_text
    return error


class ServoError(BusError):
    """A failed transaction with one or more servos.

    ids:         the servo ids at fault.
    instruction: what was sent: 'ping', 'read', 'write', 'sync_read', 'fast_sync_read', ...
    """

    kind = "servo error"
    line_stalled = False
    """True when the instruction was not even sent: replies to earlier ones were still pending."""
    deadline = False
    """True when the SDK gave up at its deadline (no reply, or one cut short): on a loaded
    machine such a reply may only be late (see ``BusLink.witness``)."""
    reply_late = False
    """True when a witness already judged this transaction's reply LATE (and read it off the
    line): proven late. Judging it again would find a clean line and call the servo silent."""

    def __init__(self, ids: Iterable[int], instruction: str, detail: str = ""):
        self.ids = sorted(int(i) for i in ids)
        self.instruction = instruction
        self.detail = detail
        text = f"{self.kind}: servo{'s' if len(self.ids) != 1 else ''} {self.ids} during {instruction}"
        super().__init__(text + (f": {detail}" if detail else ""))

    def __reduce__(self):
        return (type(self), (self.ids, self.instruction, self.detail))


class ServoTimeout(ServoError):
    """No status packet came back before the SDK's deadline."""

    kind = "timeout"


class ServoCorrupt(ServoError):
    """A reply came back but was unusable: bad CRC, partial, wrong length, malformed."""

    kind = "corrupt reply"


class ServoStatusError(ServoError):
    """The servo answered with a non-zero error number (and possibly no data).

    error: the status packet's error byte.
    """

    kind = "error status"

    def __init__(self, ids: Iterable[int], instruction: str, detail: str = "", error: int = 0):
        self.error = error
        super().__init__(ids, instruction, detail)

    def __reduce__(self):
        return (type(self), (self.ids, self.instruction, self.detail, self.error))


class ServoModelMismatch(ServoError):
    """A servo reports a model number other than the one the map declares."""

    kind = "model mismatch"


class ServoMissing(ServoError):
    """Servos listed in the map did not answer a ping."""

    kind = "missing"
