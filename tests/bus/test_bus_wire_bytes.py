"""The bytes one reading puts on the line, counted by hw_sim while puppet's own transactions
(``BusLink.group_read``, as bench/bus.py times them) read 15 servos through the real SDK: the
issue's 157 bytes for a Fast Sync Read of 15 X-series, and the Protocol 1.0 sizes the reader
bench's wire ceiling assumes (bench/bus_reader.py ``wire_ceiling``)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

import hw_sim

BENCH = Path(__file__).resolve().parents[2] / "bench"


def _bench(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("read, model, expected", [
    ("fast", "XL430-W250", 14 + 15 + 8 + 8 * 15),   # instruction 14 + 1 per id; reply 8 + 8 per servo
    ("read", "AX-12A", 16 * 15),                     # per servo: READ 8 bytes, status 8 (2 data)
    ("bulk", "MX-28", 7 + 3 * 15 + 8 * 15),          # Bulk Read 7 + 3 per servo; 8-byte statuses
])
def test_one_reading_of_15_servos_is_the_bytes_the_ceilings_count(read, model, expected):
    bus_bench = _bench("bus")
    ids = list(range(1, 16))
    with hw_sim.serve(dict.fromkeys(ids, model)) as bus:   # the bytes are the same with timing on
        timed = bus_bench._time_family(bus.port, 1_000_000, model, ids, read, 5, bus=bus)
    assert timed["bytes"] == expected
    if read == "fast":
        assert expected == 157   # the figure: 1.57 ms at 1 Mbps
    else:
        ceiling = _bench("bus_reader").wire_ceiling(model, 15, 1_000_000)
        assert ceiling == pytest.approx(1_000_000 / 10 / timed["bytes"])
