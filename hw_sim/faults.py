"""Fault kinds, faults scheduled in time, and the fault file format.

A ``Fault`` is one kind, the servo ids it hits (None = every servo), when it starts (seconds since
the bus started), how long it lasts (None = until cleared) and its parameters. Kinds:

=================  ==========================================================================
drop               the servo does not reply. params: p (probability per reply, default 1)
bad_crc            the reply's CRC is corrupted. params: p
truncate           the reply is cut short. params: p, keep (bytes kept, default half)
error_status       the reply carries an error number and no data. params: p, error (default 1;
                   on a Protocol 1.0 bus the status packet's error bits)
late               the reply is sent whole, ``ms`` later (default 20) than its turn: a reply past
                   the host's deadline, as a busy host sees one. params: p, ms. Needs the
                   server's timing model (``timing=True``); without it replies have no time
power_cycle        power off for the duration (default 0.2 s), then on: the servo reboots
power_off          power off (silent) until ``power_on`` or the end of the duration
power_on           power back on: the servo boots (RAM defaults, re-based position)
unplug             the USB adapter disappears (bus-wide); replugged after the duration if given
replug             the adapter comes back (the port path is re-created, see SimBus.port)
duplicate_id       a second servo answers with the same id: replies collide (bytes ANDed).
                   params: offset (counts its shaft differs by, default 100)
hardware_error     latch Hardware Error Status bits (alert bit in every status, torque off).
                   params: error = overload | overheating | input_voltage | electrical_shock |
                   encoder, or bits (int). Cleared only by reboot or power cycle.
noise              Present Position jitters by +-amplitude counts (default 2)
echo               half-duplex echo: the host sees its own instruction before each reply (bus-wide)
load               an external load on the shaft: params current (mA drawn holding it, default
                   800, 0..10000), heat (heating speed factor, default 1: larger heats faster,
                   0..1000), temperature (deg C the servo is at as the load starts, 0..150:
                   an already warm servo; default: as it is)
=================  ==========================================================================

Fault file (one fault per line, ``#`` comments)::

    # at_s  kind            key=value ...
    0.5     drop            ids=3 for=0.2
    1.0     power_cycle     ids=2 for=0.3
    2.0     unplug          for=0.5
    3.0     hardware_error  ids=4 error=overload
    4.0     noise           ids=1-4,7 amplitude=3
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from hw_sim.errors import FaultFileError, HwSimError
from hw_sim.servo import HW_ERROR_BITS

# kind -> {param: (type, default)}
KINDS: dict[str, dict[str, tuple[type, object]]] = {
    "drop": {"p": (float, 1.0)},
    "bad_crc": {"p": (float, 1.0)},
    "truncate": {"p": (float, 1.0), "keep": (int, None)},
    "error_status": {"p": (float, 1.0), "error": (int, 0x01)},
    "late": {"p": (float, 1.0), "ms": (float, 20.0)},
    "power_cycle": {},
    "power_off": {},
    "power_on": {},
    "unplug": {},
    "replug": {},
    "duplicate_id": {"offset": (int, 100)},
    "hardware_error": {"error": (str, "overload"), "bits": (int, None)},
    "noise": {"amplitude": (int, 2)},
    "echo": {},
    "load": {"current": (float, 800.0), "heat": (float, 1.0), "temperature": (float, None)},
}
# param -> (lowest, highest) accepted value (both included); every number must also be finite.
# Every numeric parameter of KINDS has one (a test checks). hw_sim keeps its own ranges: it
# imports nothing from puppet (puppet.limits holds the host's).
RANGES: dict[str, tuple[float, float]] = {
    "p": (0.0, 1.0),
    "keep": (0, 1024),
    "error": (0, 0x7F),        # error_status: the status packet's error number (7 bits)
    "bits": (0, 0xFF),         # hardware_error: Hardware Error Status is one byte
    "offset": (-(1 << 20), 1 << 20),
    "amplitude": (0, 4096),
    "current": (0.0, 10_000.0),  # load: mA drawn holding the shaft (X series stall: ~1.5 A)
    "heat": (0.0, 1000.0),       # load: heating speed factor (1 = as modelled)
    "temperature": (0.0, 150.0),  # load: deg C at its start (150: the model's ceiling)
    "ms": (0.0, 10_000.0),       # late: how much later the reply goes out
}
MAX_TIME_S = 1e6
"""Start times and durations in a fault file: finite, 0..MAX_TIME_S seconds."""
REPLY_KINDS = ("drop", "bad_crc", "truncate", "error_status", "late")
BUS_KINDS = ("unplug", "replug", "echo")


class FaultError(HwSimError, ValueError):
    """An invalid fault (unknown kind, bad parameter)."""


@dataclass(frozen=True)
class Fault:
    """kind: one of KINDS; ids: servo ids or None for all; start_s/duration_s: seconds since the
    bus started (duration None = until cleared); params: kind parameters with defaults filled."""

    kind: str
    ids: tuple[int, ...] | None = None
    start_s: float = 0.0
    duration_s: float | None = None
    params: dict = field(default_factory=dict)

    @classmethod
    def make(cls, kind: str, ids=None, *, start_s: float = 0.0, duration_s: float | None = None,
             **params) -> "Fault":
        """Validate and build a fault (FaultError names the bad kind or parameter)."""
        if kind not in KINDS:
            raise FaultError(f"unknown fault kind {kind!r}; known: {', '.join(KINDS)}")
        spec = KINDS[kind]
        full = {}
        for name, value in params.items():
            if name not in spec:
                known = ", ".join(spec) or "none"
                raise FaultError(f"fault {kind!r}: unknown parameter {name!r} (known: {known})")
            typ = spec[name][0]
            try:
                full[name] = typ(value) if not (typ is int and isinstance(value, str)) else int(value, 0)
            except (TypeError, ValueError):
                raise FaultError(f"fault {kind!r}: parameter {name}={value!r} is not {typ.__name__}") from None
        for name, (_, default) in spec.items():
            full.setdefault(name, default)
        for name, value in full.items():
            if name in RANGES and isinstance(value, (int, float)):
                lo, hi = RANGES[name]
                if not (math.isfinite(value) and lo <= value <= hi):
                    what = "a probability in 0..1" if name == "p" else f"in {lo:g}..{hi:g}"
                    raise FaultError(f"fault {kind!r}: {name}={value} is not {what}")
        if kind == "hardware_error" and full["bits"] is None:
            if full["error"] not in HW_ERROR_BITS:
                raise FaultError(f"fault 'hardware_error': error={full['error']!r}; known: "
                                 f"{', '.join(HW_ERROR_BITS)}")
            full["bits"] = HW_ERROR_BITS[full["error"]]
        if kind == "power_cycle" and duration_s is None:
            duration_s = 0.2
        for what, value in (("start time", start_s), ("duration", duration_s)):
            if value is not None and not (math.isfinite(value) and 0 <= value <= MAX_TIME_S):
                raise FaultError(f"fault {kind!r}: {what} {value} s is not in 0..{MAX_TIME_S:g} s")
        if ids is not None:
            ids = (int(ids),) if isinstance(ids, int) else tuple(int(i) for i in ids)
            bad = [i for i in ids if not 0 <= i <= 252]
            if bad:
                raise FaultError(f"fault {kind!r}: servo ids {bad} outside 0..252")
        return cls(kind, ids, float(start_s), duration_s, full)

    def hits(self, dxl_id: int) -> bool:
        return self.ids is None or dxl_id in self.ids


class FaultSchedule:
    """Faults ordered by start time. ``due(now)`` pops the faults whose start has come."""

    def __init__(self, faults=()):
        self.faults = sorted(faults, key=lambda f: f.start_s)
        self._next = 0

    def __len__(self) -> int:
        return len(self.faults)

    def due(self, now: float) -> list[Fault]:
        out = []
        while self._next < len(self.faults) and self.faults[self._next].start_s <= now:
            out.append(self.faults[self._next])
            self._next += 1
        return out

    def next_start(self) -> float | None:
        return self.faults[self._next].start_s if self._next < len(self.faults) else None

    @classmethod
    def from_file(cls, path: str | Path) -> "FaultSchedule":
        """Parse a fault file; FaultFileError names the file and line of the first problem."""
        path = Path(path)
        if path.exists() and not path.is_file():  # a FIFO or device would block or never end
            raise FaultFileError(path, None, "not a regular file (only regular files are read)")
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise FaultFileError(path, None, f"cannot read: {exc.strerror}") from exc
        except UnicodeDecodeError as exc:
            raise FaultFileError(path, text_line(path, exc.start), "not UTF-8 text") from None
        faults = []
        for lineno, raw in enumerate(text.splitlines(), 1):
            line = raw.split("#", 1)[0].split()
            if not line:
                continue
            if len(line) < 2:
                raise FaultFileError(path, lineno, "expected 'AT_S KIND [key=value ...]'")
            try:
                at = float(line[0])
            except ValueError:
                raise FaultFileError(path, lineno, f"start time {line[0]!r} is not a number") from None
            if "\0" in raw:
                raise FaultFileError(path, lineno, "a NUL byte: not a text file")
            kind, ids, duration, params = line[1], None, None, {}
            for item in line[2:]:
                key, eq, value = item.partition("=")
                if not eq or not value:
                    raise FaultFileError(path, lineno, f"expected key=value, got {item!r}")
                try:
                    if key == "ids":
                        ids = None if value == "all" else parse_ids(value)
                    elif key == "for":
                        duration = float(value.rstrip("s"))
                    else:
                        params[key] = value
                except ValueError as exc:
                    raise FaultFileError(path, lineno, f"bad {key}={value!r}: {exc}") from None
            try:
                faults.append(Fault.make(kind, ids, start_s=at, duration_s=duration, **params))
            except FaultError as exc:
                raise FaultFileError(path, lineno, str(exc)) from None
        return cls(faults)


def text_line(path: Path, offset: int) -> int:
    """The 1-based line of byte ``offset`` in the file at ``path``."""
    with open(path, "rb") as f:
        return f.read(offset).count(b"\n") + 1


def parse_ids(text: str) -> list[int]:
    """'1-3,7' -> [1, 2, 3, 7]; ValueError on anything else."""
    ids: list[int] = []
    for part in text.split(","):
        part = part.strip()
        lo, dash, hi = part.partition("-")
        ends = (int(lo), int(hi)) if dash else (int(part),)
        for i in ends:
            if not 0 <= i <= 252:
                raise ValueError(f"servo id {i} is outside 0..252")
        if ends[-1] < ends[0]:
            raise ValueError(f"range {part!r} is backwards")
        ids.extend(range(ends[0], ends[-1] + 1))
    return ids


def make_schedule(spec) -> FaultSchedule:
    """A schedule from None, a FaultSchedule, a list of Faults, or a fault file path."""
    if spec is None:
        return FaultSchedule()
    if isinstance(spec, FaultSchedule):
        return spec
    if isinstance(spec, (list, tuple)):
        return FaultSchedule(spec)
    return FaultSchedule.from_file(spec)
