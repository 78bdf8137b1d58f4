"""``puppet scan`` through the real SDK on hw_sim: both protocols, one baud or several, and
what it prints (baud, protocol, id, model, firmware)."""

from __future__ import annotations

from click.testing import CliRunner

import hw_sim
from puppet.bus.scan import P1_PASSES, SCAN_BAUDS, Found, scan
from puppet.cli import main


def test_scan_prints_protocol_model_and_firmware_of_every_servo():
    with hw_sim.serve({1: "XL330-M288", 5: "XL430-W250"}) as bus:
        result = CliRunner().invoke(main, ["scan", "--port", bus.port])
        firmware = {i: bus.servo(i).get("Firmware Version") for i in (1, 5)}
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.stdout.splitlines()]
    assert rows[0] == ["baud", "protocol", "id", "model", "number", "firmware"]
    assert rows[1:] == [["1000000", "2.0", "1", "XL330-M288", "1200", str(firmware[1])],
                        ["1000000", "2.0", "5", "XL430-W250", "1060", str(firmware[5])]]


def test_scan_finds_servos_only_at_their_own_baud_rate():
    with hw_sim.serve({3: "XL430-W250", 7: "XM430-W350"}, baud=57600, strict_baud=True) as bus:
        found = scan(bus.port, (1_000_000, 57600, 4_000_000))
        firmware = {i: bus.servo(i).get("Firmware Version") for i in (3, 7)}
    assert found == [Found(57600, 2.0, 3, 1060, firmware[3]), Found(57600, 2.0, 7, 1020, firmware[7])]
    assert [f.model for f in found] == ["XL430-W250", "XM430-W350"]


def test_scan_baud_all_tries_every_standard_rate_the_sdk_opens():
    assert SCAN_BAUDS[0] == 9600 and SCAN_BAUDS[-1] == 4_000_000
    assert {57600, 1_000_000, 2_000_000, 3_000_000} <= set(SCAN_BAUDS)
    assert 4_500_000 not in SCAN_BAUDS  # an X430 rate the SDK's PortHandler refuses


def test_scan_of_a_silent_bus_says_what_to_check():
    with hw_sim.serve({1: "XL330-M288"}) as bus:
        bus.inject("power_off", ids=[1])
        port = bus.port
        result = CliRunner().invoke(main, ["scan", "--port", port, "--baud", "57600"])
    assert result.exit_code == 1
    assert (f"Error: port {port}: no servo answered a ping at 57600 bps (Protocol 1.0 nor "
            "2.0)") in result.output


def test_scan_refuses_a_bad_baud_naming_the_option():
    result = CliRunner().invoke(main, ["scan", "--port", "/dev/null", "--baud", "fast"])
    assert result.exit_code == 2
    assert "--baud" in result.output and "'fast'" in result.output


def test_scan_finds_protocol_1_servos_and_names_their_protocol():
    with hw_sim.serve({2: "AX-12A", 9: "MX-28"}) as bus:
        result = CliRunner().invoke(main, ["scan", "--port", bus.port])
        firmware = {i: bus.servo(i).get("Firmware Version") for i in (2, 9)}
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.stdout.splitlines()[1:]]
    assert rows == [["1000000", "1.0", "2", "AX-12A", "12", str(firmware[2])],
                    ["1000000", "1.0", "9", "MX-28", "29", str(firmware[9])]]


def test_scan_across_bauds_finds_protocol_1_servos_at_their_rate_only():
    with hw_sim.serve({4: "AX-18A"}, baud=57600, strict_baud=True) as bus:
        found = scan(bus.port, (1_000_000, 57600), protocols=(2.0, 1.0))
        firmware = bus.servo(4).get("Firmware Version")
    assert found == [Found(57600, 1.0, 4, 18, firmware)]
    assert found[0].model == "AX-18A"


def test_a_protocol_1_scan_pings_the_missing_ids_again_and_says_what_it_found(monkeypatch):
    """Servos 3 and 5 do not answer the first pass (their replies dropped, as replies late on a
    busy host are lost); the fault is lifted once that pass is over: the second pass finds them
    and says so; every pass runs (a busy host can lose the same reply twice)."""
    from puppet.bus.link import BusLink

    models = {1: "AX-12A", 2: "AX-12A", 3: "AX-18A", 4: "MX-28", 5: "AX-12A", 6: "AX-12A"}
    with hw_sim.serve(models) as bus:
        bus.inject("drop", ids=[3, 5])
        passes = []
        ping_each = BusLink.ping_each

        def counted(link, ids):
            ids = list(ids)
            found = ping_each(link, ids)
            passes.append((len(ids), sorted(found)))
            bus.clear_faults()  # after the first pass
            return found

        monkeypatch.setattr(BusLink, "ping_each", counted)
        lines = []
        port = bus.port
        found = scan(port, (1_000_000,), (1.0,), log=lines.append)
    assert [f.id for f in found] == sorted(models)
    assert [f.model for f in found] == [models[i] for i in sorted(models)]
    # A loaded host may lose more replies than the dropped ones, and lose them again in the
    # next pass: a later pass finds those too.
    first = passes[0]
    assert first[0] == 254 and set(first[1]) <= {1, 2, 4, 6} and first[1]
    assert len(passes) == P1_PASSES  # a pass that finds nothing new does not end the scan
    later = [(n, ids) for n, (_, ids) in enumerate(passes[1:], start=2) if ids]
    assert {3, 5} <= {i for _, ids in later for i in ids}
    n, ids = later[0]
    assert lines[0] == (f"{port} at 1000000 bps, Protocol 1.0: pass {n} found servo"
                        f"{'s' if len(ids) > 1 else ''} {ids} that pass {n - 1} missed (replies "
                        "late: a busy host or a noisy line)")
    assert len(lines) == len(later)


def test_a_protocol_1_scan_of_nothing_pings_once(monkeypatch):
    from puppet.bus.link import BusLink

    calls = []
    ping_each = BusLink.ping_each
    monkeypatch.setattr(BusLink, "ping_each",
                        lambda link, ids: calls.append(1) or ping_each(link, ids))
    with hw_sim.serve({1: "XL330-M288"}) as bus:  # a Protocol 2.0 bus: nothing answers 1.0
        assert scan(bus.port, (1_000_000,), (1.0,)) == []
    assert calls == [1]


def test_a_protocol_1_pass_that_hears_only_late_replies_is_followed_by_another(monkeypatch):
    """Every reply of the first pass past its deadline (a starved host: the pass finds nothing),
    the fault lifted once that pass is over: the late bytes on the line say something answers,
    so the next pass runs and finds the servos (it ended the scan with nothing before)."""
    from puppet.bus.link import BusLink

    models = {2: "AX-12A", 9: "MX-28"}
    with hw_sim.serve(models, timing=True) as bus:
        bus.inject("late", ms=30)
        passes = []
        ping_each = BusLink.ping_each

        def counted(link, ids):
            found = ping_each(link, list(ids))
            passes.append((sorted(found), link.late_bytes))
            bus.clear_faults()  # after the first pass
            return found

        monkeypatch.setattr(BusLink, "ping_each", counted)
        found = scan(bus.port, (1_000_000,), (1.0,))
    assert passes[0] == ([], True)
    assert [f.id for f in found] == sorted(models)
