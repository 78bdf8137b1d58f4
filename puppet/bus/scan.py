"""Finding the servos on a bus: every protocol, at one line speed or at each standard one.

A bus carries one protocol but a port may be wired to either, and a servo answers only at its
own baud rate, so ``scan`` asks at each rate with each protocol: a Protocol 2.0 broadcast ping
(every servo answers in turn; the SDK waits its whole window, ~0.8 s at 1 Mbit/s), then, since
Protocol 1.0 has no broadcast ping, a ping of each id 0..253 (a silent id costs one SDK
deadline: ~4 ms at 1 Mbit/s with a 1 ms latency timer, about 1.5 s for the 254 ids). A Protocol
1.0 ping carries no data: the model number and firmware are read after it (``BusLink.ping``).

A reply later than that deadline (a busy host, a noisy line) is lost, so where a Protocol 1.0
pass found servos the ids that did not answer are pinged again, ``P1_PASSES`` passes in all (a
pass that finds nothing new does not end it: a busy host can lose the same reply twice, about
1.5 s a pass at 1 Mbit/s); a pass that found more is said (``log``). A Protocol 2.0 broadcast ping
waits its whole window for every reply, so one is asked once (``puppet release`` pings twice).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
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


P1_PASSES = 3
"""Passes of Protocol 1.0 pings, the first over every id, the others over the ids that did not
answer (see the module text)."""
P1_IDS = range(254)
"""The ids a Protocol 1.0 scan pings (254 is the broadcast id)."""


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
         latency_ms: int | None = None, log: Callable[[str], None] = lambda _line: None
         ) -> list[Found]:
    """Ping ``port`` at each of ``bauds`` with each of ``protocols`` -> every servo that
    answered, in that order (ids ascending within each). log: a line for each Protocol 1.0
    pass that found servos the one before missed. PortError (PortInUse) when the port cannot
    be had."""
    out: list[Found] = []
    for baud in bauds:
        for protocol in protocols:
            if protocol not in PROTOCOLS:
                raise ValueError(f"scan: protocol {protocol!r} is not one of {PROTOCOLS}")
            link = BusLink(port, baud=baud, latency_ms=latency_ms, protocol=protocol)
            try:
                link.open()
                found = link.broadcast_ping() if protocol != 1.0 else _ping_p1(link, baud, log)
            finally:
                link.close()
            out += [Found(baud, protocol, i, number, firmware)
                    for i, (number, firmware) in sorted(found.items())]
    return out


def _ping_p1(link: BusLink, baud: int, log: Callable[[str], None]) -> dict:
    """Protocol 1.0: every id pinged, then again those that did not answer, ``P1_PASSES``
    passes in all where the first found any or heard a reply past its deadline (a busy host can
    miss every reply of a pass) -> {id: (model number, firmware)}."""
    found = link.ping_each(P1_IDS)
    for n in range(2, P1_PASSES + 1):
        if not found and not link.late_bytes:
            break  # nothing of this protocol at this rate
        more = link.ping_each([i for i in P1_IDS if i not in found])
        if not more:
            continue  # a busy host may have lost the same replies again: one more pass
        found |= more
        log(f"{link.port_name} at {baud} bps, Protocol 1.0: pass {n} found servo"
            f"{'s' if len(more) > 1 else ''} {sorted(more)} that pass {n - 1} missed (replies "
            "late: a busy host or a noisy line)")
    return found


__all__ = ["Found", "scan", "SCAN_BAUDS", "SDK_BAUDS"]
