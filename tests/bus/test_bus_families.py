"""A Protocol 2.0 bus of several families (XL-320's own table, MX(2.0), X-series) read through
the real SDK on hw_sim: one Sync Read per Present Position item, the XL-320's dead zone flagged,
a fault on the XL-320 isolated and recovered."""

from __future__ import annotations

import time

import hw_sim
from puppet.bus import ServoReader
from puppet.bus import health as hs

SERVOS = {1: "XL-320", 2: "XL430-W250", 3: "MX-28(2.0)"}


def _read_until(reader, cond, what, timeout_s=60.0):
    deadline = time.monotonic() + timeout_s
    while True:
        reading = reader.read()
        if cond(reading):
            return reading
        assert time.monotonic() < deadline, f"no reading with {what}: {reader.health}"


def _sync_reads(traffic) -> list[tuple[int, int, list[int]]]:
    """Protocol 2.0 Sync Read (0x82) instructions the host sent: (address, size, ids)."""
    out = []
    for _, way, data in traffic:
        at = 0
        while way == "rx" and (at := data.find(b"\xff\xff\xfd\x00\xfe", at)) >= 0:
            length = data[at + 5] | data[at + 6] << 8
            if data[at + 7] == 0x82:
                p = data[at + 8: at + 5 + length]
                out.append((p[0] | p[1] << 8, p[2] | p[3] << 8, list(p[4:])))
            at += 7 + length
    return out


def test_one_sync_read_per_present_position_item():
    with hw_sim.serve(SERVOS) as bus:
        bus.set_positions({1: 2000, 2: 2500, 3: 3000})
        reader = ServoReader(bus.port, SERVOS, latency_ms=6)
        try:
            reader.open()
            assert reader.report.read_mode == "sync_read"   # neither XL-320 nor MX(2.0) has Fast
            reading = _read_until(reader, lambda r: r.ok.all(), "a clean reading")
            assert reading.ticks.tolist() == [bus.servo(i).get("Present Position") for i in SERVOS]
            bus.traffic()
            reader.read()
            reads = _sync_reads(bus.traffic())
        finally:
            reader.close()
    # One read of the frame's Present Positions per item, each listing its own servos.
    assert sorted(r for r in reads if r[0] in (37, 132)) == [(37, 2, [1]), (132, 4, [2, 3])]


def test_xl320_dead_zone_and_a_fault_on_it_are_flagged_and_recovered():
    with hw_sim.serve(SERVOS) as bus:
        bus.set_positions({1: 2048, 2: 2500, 3: 3000})
        reader = ServoReader(bus.port, SERVOS, latency_ms=6)
        try:
            reader.open()
            rest = _read_until(reader, lambda r: r.ok.all(), "a clean reading")
            bus.set_positions({1: 4096})                 # half a turn away: its dead zone
            held = _read_until(reader, lambda r: reader.health[1].dead_zone, "dead zone")
            assert held.ticks[0] == rest.ticks[0] and not held.ok[0]
            bus.set_positions({1: 2048})
            _read_until(reader, lambda r: r.ok.all(), "out of the dead zone")
            bus.inject("drop", ids=[1])
            _read_until(reader, lambda r: reader.health[1].state != hs.OK, "servo 1 flagged")
            reading = _read_until(reader, lambda r: r.ok.tolist() == [False, True, True],
                                  "the others flowing")
            assert reading.ticks[0] == rest.ticks[0]
            bus.clear_faults()
            assert _read_until(reader, lambda r: r.ok.all(), "back").ticks.tolist() == rest.ticks.tolist()
        finally:
            reader.close()
