"""Each hw_sim fault, read through the real SDK: the loop goes on, the right servo is flagged,
the others keep flowing, and recovery is automatic."""

from __future__ import annotations

import time

import numpy as np
import pytest

from puppet.bus import ServoCorrupt, ServoStatusError, ServoTimeout
from puppet.bus import health as hs

IDS = (1, 2, 3, 4)
AT_REST = {1: 1000, 2: 2000, 3: 3000, 4: 4000}


def _flowing_except(reading, bad_id):
    """ok is False for ``bad_id`` only."""
    return reading.ok.tolist() == [i != bad_id for i in IDS]


def _start(sim, open_reader, **reader_kwargs):
    bus = sim()
    bus.set_positions(AT_REST)
    reader = open_reader(bus, **reader_kwargs)
    deadline = time.monotonic() + 60
    while not reader.read().ok.all():            # a loaded machine may need a moment
        assert time.monotonic() < deadline, f"no clean reading: {reader.health}"
    reader.log.drain()
    return bus, reader


@pytest.mark.parametrize("kind,error_type", [
    ("drop", ServoTimeout),
    ("bad_crc", ServoCorrupt),
    ("truncate", ServoCorrupt),
    ("error_status", ServoStatusError),
])
@pytest.mark.parametrize("mode", ["fast_sync_read", "sync_read"])
def test_reply_fault_flags_one_servo_and_recovers(sim, open_reader, read_until, read_n, kind,
                                                  error_type, mode):
    bus, reader = _start(sim, open_reader, read_mode=mode)
    bus.inject(kind, ids=[3])
    during = []
    read_until(reader, lambda r: reader.health[3].state != hs.OK, what="servo 3 flagged", seen=during)
    first_error = reader.health[3].last_error
    read_until(reader, lambda r: _flowing_except(r, 3), what="the other three flowing", seen=during)
    during += read_n(reader, 5)
    for r in during:
        assert r.ticks[2] == 3000                 # servo 3 holds its last good value
        assert not r.ok[2]
    assert all(reader.health[i].state == hs.OK for i in (1, 2, 4))  # the others never booked
    h = reader.health[3]
    assert isinstance(first_error, error_type)
    assert first_error.ids == [3]
    assert h.state != hs.OK
    assert {1, 2, 4} <= set(reader.group)         # the others were never taken out of the group
    bus.clear_faults()
    read_until(reader, lambda r: r.ok.all(), what="all ok after the fault ends")
    assert reader.health[3].state == hs.OK
    assert "servo_recovered" in {e.kind for e in reader.log.events if e.ids == (3,)}


def test_dead_servo_leaves_the_group_and_costs_little(sim, open_reader, read_until, read_n):
    bus, reader = _start(sim, open_reader, probe_period_s=0.05)
    bus.inject("drop", ids=[2])
    read_until(reader, lambda r: reader.health[2].state == hs.MISSING, what="servo 2 missing")
    assert reader.group == (1, 3, 4)
    # A dead servo costs one timeout per probe, not one per reading: counted, not timed.
    failures = reader.health[2].failures
    t0 = time.monotonic()
    readings = read_n(reader, 40)
    probes = reader.health[2].failures - failures
    assert probes <= (time.monotonic() - t0) / 0.05 + 1
    assert probes < len(readings)
    read_until(reader, lambda r: _flowing_except(r, 2), what="the other three flowing")
    assert all(not r.ok[1] and r.ticks[1] == 2000 for r in readings)


def test_power_cycle_is_unwrapped_and_reconfigured(sim, open_reader, read_until, kinds):
    bus, reader = _start(sim, open_reader)
    bus.set_positions({1: 5000})                  # past one turn, torque off
    read_until(reader, lambda r: r.ok.all() and r.ticks[0] == 5000, what="servo 1 at 5000")
    bus.inject("power_off", ids=[1])              # a power cycle, its two ends in our hands
    held = read_until(reader, lambda r: not r.ok[0] and r.ok[1:].all(), what="servo 1 flagged")
    assert held.ticks[0] == 5000
    read_until(reader, lambda r: reader.health[1].state == hs.MISSING, what="servo 1 missing")
    bus.inject("power_on", ids=[1])
    reading = read_until(reader, lambda r: r.ok.all(), what="servo 1 back")
    # The servo re-based to 5000 - 4096 = 904; the reader keeps the count continuous.
    assert bus.servo(1).get("Present Position") == 904
    assert reading.ticks[0] == 5000
    assert reader.health[1].rebases == 1
    assert {"servo_missing", "servo_recovered", "rebased", "reconfigured"} <= kinds(reader)
    # The reboot is told by the Realtime Tick at the next health check.
    read_until(reader, lambda r: reader.health[1].reboots == 1, what="reboot detected")
    assert bus.servo(1).get("Return Delay Time") == 0
    bus.set_positions({1: 5010})
    assert read_until(reader, lambda r: r.ok.all() and r.ticks[0] == 5010, what="motion after").ok.all()


def test_power_off_until_power_on(sim, open_reader, read_until):
    bus, reader = _start(sim, open_reader)
    bus.inject("power_off", ids=[4])
    read_until(reader, lambda r: reader.health[4].state == hs.MISSING, what="servo 4 missing")
    read_until(reader, lambda r: _flowing_except(r, 4), what="the other three flowing")
    assert reader.health[4].state == hs.MISSING
    bus.inject("power_on", ids=[4])
    read_until(reader, lambda r: r.ok.all(), what="servo 4 back")
    assert reader.group == IDS


def test_unplug_and_replug_rebuilds_the_port(sim, open_reader, read_until, read_n, kinds):
    bus, reader = _start(sim, open_reader)
    bus.inject("unplug")
    read_until(reader, lambda r: not reader.port_up, what="port lost")  # must not raise
    readings = read_n(reader, 5)
    assert not readings[-1].ok.any()
    assert readings[-1].ticks.tolist() == [1000, 2000, 3000, 4000]
    assert not reader.port_up
    assert all(h.state == hs.PORT_DOWN for h in reader.health.values())
    bus.inject("replug")
    reading = read_until(reader, lambda r: r.ok.all(), what="all ok after replug")
    assert reading.ticks.tolist() == [1000, 2000, 3000, 4000]
    assert {"port_lost", "port_restored"} <= kinds(reader)
    assert reader.port_up


def test_unplug_with_duration_recovers_by_itself(sim, open_reader, read_until):
    bus, reader = _start(sim, open_reader)
    bus.inject("unplug", duration_s=0.3)
    read_until(reader, lambda r: not r.ok.any(), what="port lost")
    read_until(reader, lambda r: r.ok.all(), what="port back")
    assert reader.log.counts["port_restored"] == 1


@pytest.mark.parametrize("mode", ["fast_sync_read", "sync_read"])
def test_duplicate_id_is_told_from_corruption(sim, open_reader, read_until, kinds, mode):
    bus, reader = _start(sim, open_reader, read_mode=mode)
    bus.inject("duplicate_id", ids=[2], offset=100)
    readings = []
    read_until(reader, lambda r: reader.health[2].state == hs.DUPLICATE, what="duplicate found",
               seen=readings)
    read_until(reader, lambda r: _flowing_except(r, 2), what="the others flowing", seen=readings)
    assert reader.health[2].state == hs.DUPLICATE
    assert "duplicate_id" in kinds(reader)
    assert all(r.ticks[1] == 2000 for r in readings)  # never the collided value
    bus.clear_faults()
    read_until(reader, lambda r: r.ok.all(), what="servo 2 back")
    assert reader.health[2].state == hs.OK


def test_a_burst_of_bad_crcs_is_not_taken_for_a_duplicate_id(sim, open_reader, read_until, kinds):
    # Replies of servo 2 corrupted 30 % of the time: ping answers now and then, and so do position
    # reads: that is a noisy line, not two servos on one id (whose position replies never pass).
    bus, reader = _start(sim, open_reader)
    bus.inject("bad_crc", ids=[2], p=0.3)
    read_until(reader, lambda r: reader.health[2].state in (hs.CORRUPT, hs.DUPLICATE),
               what="servo 2 diagnosed after corrupt replies in a row")
    assert reader.health[2].state == hs.CORRUPT
    assert "duplicate_id" not in kinds(reader) and "corrupt" in kinds(reader)


def test_hardware_error_is_reported_and_cleared_by_reboot(sim, open_reader, read_until, kinds):
    bus, reader = _start(sim, open_reader)
    bus.inject("hardware_error", ids=[3], error="overload")
    read_until(reader, lambda r: "hardware_error" in kinds(reader), what="hardware error event")
    event = [e for e in reader.log.events if e.kind == "hardware_error"][0]
    assert event.ids == (3,) and "overload" in event.detail
    read_until(reader, lambda r: "reboot_sent" in kinds(reader), what="reboot")
    assert bus.servo(3).hardware_error == 0
    read_until(reader, lambda r: r.ok.all() and reader.health[3].hardware_error == 0,
               what="hardware error cleared")
    assert reader.read().ticks[2] == 3000


def test_hardware_error_without_auto_reboot_stays_flagged(sim, open_reader, read_until):
    bus, reader = _start(sim, open_reader, auto_reboot=False, health_period_s=0.05)
    bus.inject("hardware_error", ids=[1], bits=0x04)
    read_until(reader, lambda r: reader.health[1].hardware_error == 0x04, what="flagged")
    read_until(reader, lambda r: r.ok.all(), what="a full reading")  # a torque-off sensor still reads
    assert reader.health[1].alert                 # the alert bit, seen in the group read
    assert bus.servo(1).hardware_error == 0x04
    reader.reboot(1)
    read_until(reader, lambda r: r.ok.all() and reader.health[1].hardware_error == 0,
               what="cleared after the offered reboot")


def test_noise_flags_the_noisy_servo(sim, open_reader, read_until):
    bus, reader = _start(sim, open_reader)
    bus.inject("noise", ids=[4], amplitude=40)
    read_until(reader, lambda r: reader.health[4].noisy, what="servo 4 noisy")
    reading = read_until(reader, lambda r: r.ok.all(), what="a full reading")
    assert abs(int(reading.ticks[3]) - 4000) <= 40
    assert [reader.health[i].noisy for i in IDS[:3]] == [False, False, False]
    assert {e.ids for e in reader.log.events if e.kind == "noisy"} == {(4,)}   # only servo 4
    bus.clear_faults()
    read_until(reader, lambda r: not reader.health[4].noisy, what="quiet again")


def test_echo_is_harmless(sim, open_reader, read_until, read_n):
    bus, reader = _start(sim, open_reader)
    bus.inject("echo")
    readings = read_n(reader, 20)
    read_until(reader, lambda r: r.ok.all(), what="a full reading", seen=readings)
    assert all(r.ticks.tolist() == [1000, 2000, 3000, 4000] for r in readings)
    assert all(h.state == hs.OK for h in reader.health.values())


def test_implausible_jump_is_held_then_taken_after_a_gap(sim, open_reader, read_until):
    # A 2 s window: a machine stalled for longer than the default 0.1 s between two readings
    # would (rightly) take the jump at once.
    bus, reader = _start(sim, open_reader, jump_window_s=2.0)
    bus.set_positions({4: 6500})                  # 2500 counts in one step: no shaft does that
    seen = []
    read_until(reader, lambda r: "implausible jump 4000 -> 6500" in str(reader.health[4].last_error),
               what="the jump judged implausible", seen=seen)
    # Kept failing, the servo is probed alone; after a gap its value is taken.
    reading = read_until(reader, lambda r: r.ok.all(), what="taken after the gap", seen=seen)
    assert reading.ticks[3] == 6500
    assert all(r.ticks[3] == 4000 for r in seen[:-1])   # held, never a wrong value


def test_ticks_out_of_limits_are_flagged_not_taken(sim, open_reader, read_until):
    bus, reader = _start(sim, open_reader, limits={2: (0, 2050)})
    bus.set_positions({2: 2100})
    reading = read_until(reader, lambda r: not r.ok[1], what="servo 2 out of limits")
    assert reading.ticks[1] == 2000
    assert reader.health[2].out_of_limits
    bus.set_positions({2: 2040})
    assert read_until(reader, lambda r: r.ok.all(), what="back in limits").ticks[1] == 2040
    assert not reader.health[2].out_of_limits
    assert np.array_equal(reader.ids, IDS)


def test_fast_motion_read_at_uneven_intervals_is_not_noise(sim, open_reader):
    bus = sim(motion="spin")  # a full turn every 2 s: ~2000 ticks/s on every servo
    reader = open_reader(bus)
    rng = np.random.default_rng(0)
    for _ in range(150):
        reader.read()
        time.sleep(float(rng.uniform(0.0, 0.006)))
    assert not any(reader.health[i].noisy for i in IDS)
    assert reader.log.counts.get("noisy", 0) == 0
