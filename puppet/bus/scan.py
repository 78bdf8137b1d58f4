"""Finding the servos on a bus: every protocol, at one line speed or at each standard one.

A bus carries one protocol but a port may be wired to either, and a servo answers only at its
own baud rate, so ``scan`` asks at each rate with each protocol: a Protocol 2.0 broadcast ping
(every servo answers in turn; the SDK waits its whole window, ~0.8 s at 1 Mbit/s), then, since
Protocol 1.0 has no broadcast ping, a ping of each id 0..253 (a silent id costs one SDK
deadline: ~4 ms at 1 Mbit/s with a 1 ms latency timer, about 1.5 s for the 254 ids). A Protocol
1.0 ping carries no data: the model number and firmware are read after it (``BusLink.ping``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from puppet.bus.codec import PROTOCOLS
from puppet.bus.link import BusLink
from puppet.servo_models import MODELS, MODELS_BY_NUMBER

SDK_BAUDS = frozenset((9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
                       1_000_000, 1_152_000, 2_000_000, 2_500_000, 3_000_000, 3_500_000,
                       4_000_000))
"""The rates dynamixel_sdk's PortHandler opens (``getCFlagBaud``; others it refuses)."""
SCAN_BAUDS = tuple(sorted({b for m in MODELS.values() for b in m.baud_rates} & SDK_BAUDS))
"""``scan --baud all``: every rate a model of the table can select that the SDK opens,
ascending (9600 .. 4 Mbit/s)."""


@dataclass(frozen=True)
class Found:
    """A servo that answered a ping: the line speed and protocol it answered at, its id, Model
    Number and firmware version; ``model`` its name in the table (None: a model puppet does not
    know)."""

    baud: int
    protocol: float
    id: int
    number: int
    firmware: int

    @property
    def model(self) -> str | None:
        model = MODELS_BY_NUMBER.get(self.number)
        return model.name if model is not None and model.protocol == self.protocol else None


def scan(port: str, bauds: Iterable[int], protocols: Iterable[float] = (2.0, 1.0),
         latency_ms: int | None = None) -> list[Found]:
    """Ping ``port`` at each of ``bauds`` with each of ``protocols`` -> every servo that
    answered, in that order (ids ascending within each). PortError (PortInUse) when the port
    cannot be had."""
    out: list[Found] = []
    for baud in bauds:
        for protocol in protocols:
            if protocol not in PROTOCOLS:
                raise ValueError(f"scan: protocol {protocol!r} is not one of {PROTOCOLS}")
            link = BusLink(port, baud=baud, latency_ms=latency_ms, protocol=protocol)
            try:
                link.open()
                found = link.broadcast_ping()
            finally:
                link.close()
            out += [Found(baud, protocol, i, number, firmware)
                    for i, (number, firmware) in sorted(found.items())]
    return out


__all__ = ["Found", "scan", "SCAN_BAUDS", "SDK_BAUDS"]
