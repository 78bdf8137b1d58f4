"""A Protocol 1.0 bus through the real SDK (``PacketHandler(1.0)``) on hw_sim: MX servos read by
one Bulk Read, AX servos by a Read each, and every hw_sim fault kind handled as on Protocol 2.0:
the loop goes on, the right servo is flagged, the others keep flowing, recovery is automatic."""

from __future__ import annotations

import time

import pytest

import hw_sim
from puppet.bus import BusError, ServoCorrupt, ServoReader, ServoStatusError, ServoTimeout
from puppet.bus import health as hs

LATENCY_MS = 6  # as tests/bus/conftest.py: a failed read costs ~14 ms
SERVOS = {1: "AX-12A", 2: "AX-18A", 3: "MX-28", 4: "MX-64"}
IDS = tuple(SERVOS)
AX, MX = 2, 3  # a servo read alone, a servo of the Bulk Read
SHAFT = {1: 1900, 2: 2100, 3: 1000, 4: 3000}
"""Rest shaft positions (hw_sim's 4096 counts per turn, 2048 the middle): inside every
AX's 300°."""


@pytest.fixture
def p1_sim():
    """Factory: p1_sim(servos=SERVOS, **serve_kwargs) -> a running SimBus (stopped after)."""
    stack = []

    def start(servos=SERVOS, **kwargs):
        cm = hw_sim.serve(servos, **kwargs)
        bus = cm.__enter__()
        stack.append(cm)
        return bus

    yield start
    for cm in reversed(stack):
        cm.__exit__(None, None, None)


@pytest.fixture
def p1_reader():
    readers = []

    def make(bus, servos=SERVOS, **kwargs):
        kwargs.setdefault("latency_ms", LATENCY_MS)
        reader = ServoReader(bus.link, servos, **kwargs)
        reader.open()
        readers.append(reader)
        return reader

    yield make
    for reader in readers:
        reader.close()


def read_until(reader, cond, timeout_s=60.0, what="condition", seen=None):
    deadline = time.monotonic() + timeout_s
    while True:
        reading = reader.read()
        if seen is not None:
            seen.append(reading)
        if cond(reading):
            return reading
        if time.monotonic() > deadline:
            raise AssertionError(f"no reading with {what} within {timeout_s} s; last: {reading}; "
                                 f"health: {reader.health}")


def kinds(reader) -> set[str]:
    return {e.kind for e in reader.log.events}


def present(bus, ids=IDS) -> list[int]:
    """Each servo's Present Position as the simulator holds it."""
    return [bus.servo(i).get("Present Position") for i in ids]


def _start(p1_sim, p1_reader, **reader_kwargs):
    bus = p1_sim()
    bus.set_positions(SHAFT)
    reader = p1_reader(bus, **reader_kwargs)
    rest = read_until(reader, lambda r: r.ok.all(), what="a clean reading")
    assert rest.ticks.tolist() == present(bus)
    reader.log.drain()
    return bus, reader, rest.ticks.tolist()


def _flowing_except(reading, bad_id):
    return reading.ok.tolist() == [i != bad_id for i in IDS]


def _instructions(traffic) -> list[tuple[int, int, bytes]]:
    """Protocol 1.0 instruction packets the host sent: (id, instruction, parameters)."""
    out = []
    for _, way, data in traffic:
        if way != "rx":
            continue
        at = 0
        while (at := data.find(b"\xff\xff", at)) >= 0 and at + 4 < len(data):
            length = data[at + 3]
            out.append((data[at + 2], data[at + 4], bytes(data[at + 5: at + 3 + length])))
            at += 4 + length
    return out


def test_mx_servos_are_read_by_one_bulk_read_and_ax_servos_one_read_each(p1_sim, p1_reader):
    bus, reader, rest = _start(p1_sim, p1_reader)
    assert reader.report.read_mode == "bulk_read + read"
    assert reader.link.protocol == 1.0
    bus.traffic()
    assert reader.read().ticks.tolist() == rest
    sent = _instructions(bus.traffic())
    # One Bulk Read (0x92) of Present Position (36, 2 bytes) of the MX servos, in map order,
    bulk = [p for i, ins, p in sent if i == 0xFE and ins == 0x92]
    assert bulk == [bytes([0x00, 2, 3, 36, 2, 4, 36])]
    # and one Read (0x02) of 36, 2 bytes, per AX servo: nothing else.
    reads = [(i, p) for i, ins, p in sent if ins == 0x02]
    assert reads == [(1, bytes([36, 2])), (2, bytes([36, 2]))]
    assert len(sent) == 3


@pytest.mark.parametrize("servos,mode", [({1: "AX-12A", 2: "RX-28"}, "read"),
                                         ({5: "MX-106", 6: "MX-12W"}, "bulk_read")])
def test_a_bus_of_one_family_reads_by_its_own_transaction(p1_sim, p1_reader, servos, mode):
    bus = p1_sim(servos)
    bus.set_positions({i: 2048 + 100 * i for i in servos})
    reader = p1_reader(bus, servos)
    assert reader.report.read_mode == mode
    reading = read_until(reader, lambda r: r.ok.all(), what="a clean reading")
    assert reading.ticks.tolist() == present(bus, servos)


def test_setup_configures_return_delay_and_torque_off_through_protocol_1(p1_sim, p1_reader):
    bus = p1_sim()
    bus.servo(1).set("Torque Enable", 1)
    reader = p1_reader(bus)
    changes = {(c.id, c.item, c.new) for c in reader.report.changes}
    assert {(i, "Return Delay Time", 0) for i in IDS} <= changes
    assert (1, "Torque Enable", 0) in changes
    assert [bus.servo(i).get("Return Delay Time") for i in IDS] == [0, 0, 0, 0]
    assert bus.servo(1).get("Torque Enable") == 0
    assert {i: info.model_number for i, info in reader.report.found.items()} == {
        1: 12, 2: 18, 3: 29, 4: 310}


@pytest.mark.parametrize("kind,params,error_type", [
    ("drop", {}, ServoTimeout),
    ("bad_crc", {}, ServoCorrupt),
    ("truncate", {}, ServoCorrupt),
    ("error_status", {"error": 0x08}, ServoStatusError),   # Protocol 1.0 range error bit
])
@pytest.mark.parametrize("bad", [AX, MX])
def test_reply_fault_flags_one_servo_and_recovers(p1_sim, p1_reader, kind, params, error_type, bad):
    bus, reader, rest = _start(p1_sim, p1_reader)
    k = IDS.index(bad)
    bus.inject(kind, ids=[bad], **params)
    during = []
    read_until(reader, lambda r: reader.health[bad].state != hs.OK, what="flagged", seen=during)
    first_error = reader.health[bad].last_error
    read_until(reader, lambda r: _flowing_except(r, bad), what="the others flowing", seen=during)
    for r in during:
        assert r.ticks[k] == rest[k] and not r.ok[k]   # holds its last good value, flagged
    assert isinstance(first_error, error_type) and first_error.ids == [bad]
    assert all(reader.health[i].state == hs.OK for i in IDS if i != bad)
    bus.clear_faults()
    read_until(reader, lambda r: r.ok.all(), what="all ok after the fault ends")
    assert "servo_recovered" in {e.kind for e in reader.log.events if e.ids == (bad,)}


@pytest.mark.parametrize("bad", [AX, MX])
def test_power_off_until_power_on_and_power_cycle(p1_sim, p1_reader, bad):
    bus, reader, rest = _start(p1_sim, p1_reader)
    bus.inject("power_off", ids=[bad])
    read_until(reader, lambda r: reader.health[bad].state == hs.MISSING, what="missing")
    assert bad not in reader.group
    read_until(reader, lambda r: _flowing_except(r, bad), what="the others flowing")
    bus.inject("power_on", ids=[bad])
    reading = read_until(reader, lambda r: r.ok.all(), what="back")
    assert reading.ticks.tolist() == rest
    assert reader.group == IDS
    assert {"servo_missing", "servo_recovered", "reconfigured"} <= kinds(reader)
    assert bus.servo(bad).get("Return Delay Time") == 0   # EEPROM: kept over the power cycle
    bus.inject("power_cycle", ids=[bad], duration_s=0.3)
    read_until(reader, lambda r: not r.ok[IDS.index(bad)], what="the power cycle seen")
    assert read_until(reader, lambda r: r.ok.all(), what="back again").ticks.tolist() == rest


def test_unplug_and_replug_rebuilds_the_port(p1_sim, p1_reader):
    bus, reader, rest = _start(p1_sim, p1_reader)
    bus.inject("unplug")
    read_until(reader, lambda r: not reader.port_up, what="port lost")
    assert all(h.state == hs.PORT_DOWN for h in reader.health.values())
    held = reader.read()
    assert not held.ok.any() and held.ticks.tolist() == rest
    bus.inject("replug")
    assert read_until(reader, lambda r: r.ok.all(), what="all ok after replug").ticks.tolist() == rest
    assert {"port_lost", "port_restored"} <= kinds(reader)


@pytest.mark.parametrize("bad", [AX, MX])
def test_duplicate_id_is_told_from_corruption(p1_sim, p1_reader, bad):
    bus, reader, rest = _start(p1_sim, p1_reader)
    bus.inject("duplicate_id", ids=[bad], offset=100)
    seen = []
    read_until(reader, lambda r: reader.health[bad].state == hs.DUPLICATE, what="duplicate",
               seen=seen)
    read_until(reader, lambda r: _flowing_except(r, bad), what="the others flowing", seen=seen)
    assert "duplicate_id" in kinds(reader)
    assert all(r.ticks[IDS.index(bad)] == rest[IDS.index(bad)] for r in seen)
    bus.clear_faults()
    read_until(reader, lambda r: r.ok.all(), what="back")


@pytest.mark.parametrize("bad", [AX, MX])
def test_hardware_error_in_the_status_is_reported_and_never_rebooted(p1_sim, p1_reader, bad):
    # Protocol 1.0 has no Hardware Error Status and no Reboot: the error byte of every status
    # carries the condition; a torque-off sensor still reads; a power cycle clears it.
    bus, reader, rest = _start(p1_sim, p1_reader, health_period_s=0.05)
    bus.inject("hardware_error", ids=[bad], error="overload")
    read_until(reader, lambda r: reader.health[bad].hardware_error == 0x20, what="flagged")
    event = [e for e in reader.log.events if e.kind == "hardware_error"][0]
    assert event.ids == (bad,) and "overload" in event.detail
    assert reader.health[bad].alert
    assert read_until(reader, lambda r: r.ok.all(), what="still reading").ticks.tolist() == rest
    assert "reboot_sent" not in kinds(reader)
    bus.inject("power_cycle", ids=[bad], duration_s=0.2)
    read_until(reader, lambda r: r.ok.all() and reader.health[bad].hardware_error == 0,
               what="cleared by the power cycle")
    assert "hardware_error_cleared" in kinds(reader)


def test_noise_flags_the_noisy_servo(p1_sim, p1_reader):
    bus, reader, rest = _start(p1_sim, p1_reader)
    bus.inject("noise", ids=[MX], amplitude=40)
    read_until(reader, lambda r: reader.health[MX].noisy, what="noisy")
    assert {e.ids for e in reader.log.events if e.kind == "noisy"} == {(MX,)}
    bus.clear_faults()
    read_until(reader, lambda r: not reader.health[MX].noisy, what="quiet again")


def test_echo_is_harmless(p1_sim, p1_reader):
    bus, reader, rest = _start(p1_sim, p1_reader)
    bus.inject("echo")
    readings = [reader.read() for _ in range(20)]
    read_until(reader, lambda r: r.ok.all(), what="a full reading", seen=readings)
    assert all(r.ticks.tolist() == rest for r in readings)
    assert all(h.state == hs.OK for h in reader.health.values())


def test_a_reading_in_the_ax_dead_zone_is_flagged_not_turned_into_an_angle(p1_sim, p1_reader):
    bus, reader, rest = _start(p1_sim, p1_reader)
    k = IDS.index(1)
    bus.set_positions({1: 2048 + 2048})  # half a turn from the middle: the dead zone's middle
    seen = []
    read_until(reader, lambda r: reader.health[1].dead_zone, what="dead zone flagged", seen=seen)
    assert bus.servo(1).get("Present Position") in (0, 1023)   # what the servo reads there
    held = read_until(reader, lambda r: _flowing_except(r, 1), what="the others flowing", seen=seen)
    assert all(r.ticks[k] == rest[k] and not r.ok[k] for r in seen)   # held, never taken
    event = [e for e in reader.log.events if e.kind == "dead_zone"][0]
    assert event.ids == (1,) and "AX-12A" in event.detail
    assert held.ticks[k] == rest[k]
    bus.set_positions({1: SHAFT[1]})
    back = read_until(reader, lambda r: r.ok.all(), what="out of the dead zone")
    assert back.ticks.tolist() == rest and not reader.health[1].dead_zone


def test_a_mixed_protocol_map_is_refused_naming_the_servos():
    with pytest.raises(ValueError) as err:
        ServoReader("/dev/null", {1: "AX-12A", 2: "XL430-W250", 3: "MX-28"})
    assert str(err.value).startswith(
        "ServoReader: the servo map: protocols mixed on one bus (Protocol 1.0: servos 1 (AX-12A), "
        "3 (MX-28); Protocol 2.0: servos 2 (XL430-W250))")


def test_a_baud_the_model_cannot_do_is_refused_naming_the_servo():
    with pytest.raises(BusError) as err:
        ServoReader("/dev/null", {1: "AX-12A", 3: "MX-28"}, baud=3_000_000)
    assert str(err.value) == ("port /dev/null: 3000000 bit/s is not a rate of servo 1 (AX-12A: up "
                              "to 1 Mbit/s)")


def test_a_command_at_a_baud_some_models_cannot_do_names_those_servos(protocol1_rig, tmp_path):
    import subprocess

    result = subprocess.run(["puppet", "record", "--rig", str(protocol1_rig), "--port", "/dev/null",
                             "--out", str(tmp_path / "t.mcap"), "--baud", "3000000", "--seconds", "1"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == [
        "Error: port /dev/null: 3000000 bit/s is not a rate of servos 1, 2, 3, 4, 5, 6, 7, 8 "
        "(AX-12A: up to 1 Mbit/s)"]     # the MX-28 (servos 9..15) run at 3 Mbit/s


def test_calibrate_captures_the_zero_pose_of_a_p1_rig(protocol1_rig, tmp_path):
    import subprocess

    from puppet.rig import Calibration, load_rig

    models = dict(load_rig(protocol1_rig).servo_map.models)
    out = tmp_path / "cal.toml"
    with hw_sim.serve(models) as bus:
        bus.set_positions({i: 2000 + i for i in models})
        result = subprocess.run(["puppet", "calibrate", "--rig", str(protocol1_rig), "--port",
                                 bus.port, "--out", str(out)], capture_output=True, text=True,
                                timeout=300)
        present = {i: bus.servo(i).get("Present Position") for i in models}
    assert result.returncode == 0, result.stderr
    zero = Calibration.load(out).zero_ticks
    assert zero == present                                   # each servo's own ticks
    assert all(0 < zero[i] < 1023 for i, m in models.items() if m == "AX-12A")
    load_rig(protocol1_rig).servo_map.calibrate(Calibration.load(out))   # limits still inside
