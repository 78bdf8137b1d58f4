"""ServoReader against hw_sim through the real dynamixel_sdk: setup and normal reading."""

from __future__ import annotations

import time

import numpy as np
import pytest

from puppet.bus import ServoMissing, ServoModelMismatch, ServoReader
from puppet.bus import health as hs

MODEL = "XL330-M288"


def test_open_configures_and_reports_changes(sim, open_reader):
    bus = sim()
    bus.servo(2).set("Torque Enable", 1)
    reader = open_reader(bus)
    report = reader.report
    assert sorted(report.found) == [1, 2, 3, 4]
    assert report.missing == []
    assert report.read_mode == "fast_sync_read"  # XL330 firmware 52 >= 46
    changed = {(c.id, c.item, c.old, c.new) for c in report.changes}
    assert {(i, "Return Delay Time", 250, 0) for i in (1, 2, 3, 4)} <= changed
    assert (2, "Torque Enable", 1, 0) in changed
    for i in (1, 2, 3, 4):
        assert bus.servo(i).get("Return Delay Time") == 0
        assert bus.servo(i).get("Torque Enable") == 0


@pytest.mark.parametrize("level", [0, 1])
def test_a_quiet_status_return_level_is_raised_to_2(sim, open_reader, level):
    bus = sim(ids=(1, 2))
    bus.servo(2).set("Status Return Level", level)
    reader = open_reader(bus, ids=(1, 2))
    assert (2, "Status Return Level", level, 2) in {(c.id, c.item, c.old, c.new) for c in reader.report.changes}
    assert bus.servo(2).get("Status Return Level") == 2
    assert bus.servo(2).get("Return Delay Time") == 0
    assert reader.report.missing == []


def test_open_again_changes_nothing(sim, open_reader):
    bus = sim()
    open_reader(bus).close()
    assert open_reader(bus).report.changes == []


def test_model_mismatch_names_the_servo(sim):
    bus = sim()
    reader = ServoReader(bus.link, {1: MODEL, 2: "XM430-W350", 3: MODEL}, latency_ms=6)
    with pytest.raises(ServoModelMismatch) as info:
        reader.open()
    assert info.value.ids == [2]
    assert "XM430-W350 (1020)" in str(info.value) and "XL330-M288 (1200)" in str(info.value)
    reader.close()


def test_missing_servo_is_flagged_and_others_flow(sim, open_reader):
    bus = sim(ids=(1, 2, 3))
    reader = open_reader(bus, ids=(1, 2, 9, 3))
    assert reader.report.missing == [9]
    reading = reader.read()
    while not reading.ok[[0, 1, 3]].all():     # a loaded machine may hold a reply: read again
        reading = reader.read()
    assert reading.ok.tolist() == [True, True, False, True]
    assert reader.health[9].state == hs.MISSING
    assert reader.group == (1, 2, 3)
    reader.close()  # one program (here: one reader) per port
    strict = ServoReader(bus.link, {1: MODEL, 9: MODEL}, latency_ms=6)
    with pytest.raises(ServoMissing) as info:
        strict.open(strict=True)
    assert info.value.ids == [9]
    strict.close()


def test_broadcast_ping_lists_servos_the_map_lacks(sim):
    bus = sim(ids=(1, 2, 5))
    reader = ServoReader(bus.link, {1: MODEL, 2: MODEL}, latency_ms=6)
    report = reader.open(broadcast_ping=True)
    assert report.unexpected == {5: 1200}
    reader.close()


@pytest.mark.parametrize("mode", ["fast_sync_read", "sync_read"])
def test_reading_at_rest_is_exact_signed_and_continuous(sim, open_reader, read_n, read_until, mode):
    bus = sim()
    # -5: negative count; 5000: past one turn; 0x00FDFFFF: data bytes FF FF FD 00 need stuffing.
    positions = {1: 100, 2: -5, 3: 5000, 4: 0x00FDFFFF}
    bus.set_positions(positions)
    reader = open_reader(bus, read_mode=mode)
    assert reader.read_mode == mode
    readings = read_n(reader, 30)
    read_until(reader, lambda r: r.ok.all(), what="a full reading", seen=readings)
    for r in readings:
        assert r.ticks.dtype == np.int32 and r.ok.dtype == bool
        assert r.ids.tolist() == [1, 2, 3, 4]
        # a servo whose read failed (a loaded machine) holds its value: never a wrong one
        assert r.ticks[r.ok].tolist() == [p for p, ok in zip(positions.values(), r.ok) if ok]
    assert all(h.state == hs.OK for h in reader.health.values())  # nothing booked failed
    stamps = [r.t_ns for r in readings]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)


def test_reading_in_motion_follows_the_simulated_shafts(sim, open_reader, read_until):
    bus = sim(motion="wave")
    reader = open_reader(bus)
    seen = []

    def moved(_):
        full = [r.ticks for r in seen if r.ok.all()]
        return len(full) >= 20 and (np.ptp(np.stack(full), axis=0) > 50).all()

    read_until(reader, moved, what="every joint moved, in 20 full readings or more", seen=seen)
    # wave amplitude 600 counts, period 2 s: at most ~1.9 counts per ms. A reading stamped t[i]
    # (its request) samples the shafts somewhere before t[i+1] (the next request); a starved
    # machine can hold a reply long, so bound each step by the readings around it, not by 20 ms.
    t_ms = np.array([r.t_ns for r in seen]) / 1e6
    for i in range(1, len(seen) - 2):
        a, b = seen[i], seen[i + 1]
        if a.ok.all() and b.ok.all():
            step = np.abs(b.ticks.astype(np.int64) - a.ticks).max()
            assert step <= 2.0 * (t_ms[i + 2] - t_ms[i - 1]) + 2, (i, step, t_ms[i - 1:i + 3])
    now = reader.read()
    sim_now = [bus.servo(i).get("Present Position") for i in (1, 2, 3, 4)]
    if now.ok.all():  # sampled between the last reading's request and now
        elapsed_ms = (time.monotonic_ns() - seen[-1].t_ns) / 1e6
        assert np.abs(now.ticks - np.array(sim_now)).max() <= 2.0 * elapsed_ms + 2


def test_read_clean_takes_the_median(sim, open_reader):
    bus = sim()
    bus.set_positions({1: 10, 2: 20, 3: 30, 4: 40})
    reader = open_reader(bus)
    zero = reader.read_clean(samples=5)
    assert zero.ok.all()
    assert zero.ticks.tolist() == [10, 20, 30, 40]


def test_read_clean_names_the_servo_that_never_reads(sim, open_reader):
    from puppet.bus import ServoTimeout
    bus = sim(ids=(1, 2))
    reader = open_reader(bus, ids=(1, 2, 7))
    with pytest.raises(ServoTimeout) as info:
        reader.read_clean(timeout_s=0.5)
    assert info.value.ids == [7]
    assert info.value.instruction == "read_clean"


def test_a_driven_servo_keeps_its_torque_and_is_never_rebooted(sim, open_reader):
    """The reader turns a sensor's torque off, never a driven servo's (its driver owns it)."""
    bus = sim(ids=(1, 2))
    bus.servo(1).set("Torque Enable", 1)
    bus.servo(2).set("Torque Enable", 1)
    reader = open_reader(bus, ids=(1, 2), driven=[1])
    assert bus.servo(1).get("Torque Enable") == 1
    assert bus.servo(2).get("Torque Enable") == 0
    with pytest.raises(ValueError, match="servo 1 is driven"):
        reader.reboot(1)
    assert bus.servo(1).get("Torque Enable") == 1
