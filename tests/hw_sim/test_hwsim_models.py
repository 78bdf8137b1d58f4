"""One model table: hw_sim's device-side copy agrees with puppet's, every model is served and
read, ``hw-sim --rig`` serves exactly a rig's servos with a motion inside its limits, and
``hw-sim --servos IDS:MODEL,...`` serves mixed models without a rig."""

from __future__ import annotations

import dataclasses
import signal
import subprocess
import sys
import time

import pytest

import hw_sim
import hw_sim.cli
from hw_sim.control_table import MODELS as SIM_MODELS
from hw_sim.control_table import TICKS_PER_TURN as SIM_TICKS_PER_TURN
from hw_sim.motion import WithinLimits
from hw_sim.servo import IDLE_CURRENT_MA
from hw_sim.rig_servos import RigFileError, RigServo, read_rig_servos
from puppet.servo_models import MODELS, TICKS_PER_TURN, ServoModel

PRESENT_POSITION = 132
SERVED_BY_THE_BUS = [name for name, m in MODELS.items() if m.items.present_position.address == 132]
"""The models the host bus reads today (X-series addresses, Protocol 2.0)."""
ITEM_NAMES = sorted({item.name for m in MODELS.values() for item in vars(m.items).values() if item})
"""Every control-table item the host names, on any model."""


def _device_facts(spec) -> dict:
    """One hw_sim model row as puppet.servo_models.ServoModel names its scalar fields."""
    return dict(name=spec.name, number=spec.number,
                fast_sync_read_firmware=spec.fast_sync_read_firmware,
                current_unit_ma=spec.current_unit_ma, current_limit=spec.current_limit,
                temperature_limit_c=spec.temp_limit,
                bus_watchdog_firmware=spec.bus_watchdog_firmware, protocol=spec.protocol,
                position_ticks=spec.position_ticks, position_range_deg=spec.position_range_deg,
                velocity_unit_rpm=spec.velocity_unit_rpm, sync_read=spec.sync_read,
                bulk_read=spec.bulk_read, baud_rates=spec.baud_rates)


def _host_facts(model: ServoModel) -> dict:
    facts = {f.name: getattr(model, f.name) for f in dataclasses.fields(ServoModel)}
    del facts["items"]
    return facts


def test_the_device_side_table_agrees_with_puppets():
    # Every per-model fact of puppet's model table, for every model, equals hw_sim's own copy.
    fields = [f.name for f in dataclasses.fields(ServoModel) if f.name != "items"]
    assert sorted(_device_facts(SIM_MODELS["XL330-M288"].spec)) == sorted(fields)
    assert {m.spec.name: _device_facts(m.spec) for m in SIM_MODELS.values()} == \
        {m.name: _host_facts(m) for m in MODELS.values()}
    assert SIM_TICKS_PER_TURN == TICKS_PER_TURN
    for model in SIM_MODELS.values():
        host = MODELS[model.name]
        assert model.protocol == host.protocol
        assert model.spec.ticks_per_turn == host.ticks_per_turn
        assert model.field("Model Number").default == host.number
        assert model.field("Temperature Limit").default == host.temperature_limit_c
        if host.current_limit is not None:
            assert model.field("Current Limit").default == host.current_limit


def test_every_item_the_host_names_sits_where_the_device_keeps_it():
    # Item by item: the host's address, size, signedness and area of each item it uses are the
    # simulator's, and the simulator has none of the host's items the model lacks.
    for model in SIM_MODELS.values():
        host = {item.name: (item.address, item.size, item.signed, item.eeprom)
                for item in vars(MODELS[model.name].items).values() if item}
        device = {name: (f.addr, f.size, f.signed, f.eeprom)
                  for name in ITEM_NAMES if (f := model.by_name.get(name))}
        assert device == host, model.name


def test_the_per_model_position_facts():
    ax, mx, xl320, x = MODELS["AX-12A"], MODELS["MX-28"], MODELS["XL-320"], MODELS["XL430-W250"]
    assert (ax.protocol, ax.position_ticks, ax.position_range_deg, ax.dead_zone_deg,
            ax.max_position, ax.ticks_per_turn) == (1.0, 1024, 300.0, 60.0, 1023, 1228.8)
    assert (mx.protocol, mx.ticks_per_turn, mx.dead_zone_deg, mx.items.present_position.address,
            mx.items.present_position.size) == (1.0, 4096, 0.0, 36, 2)
    assert (xl320.protocol, xl320.ticks_per_turn, xl320.items.present_position.address,
            xl320.items.present_position.size) == (2.0, 1228.8, 37, 2)
    assert (x.ticks_per_turn, x.items.present_position.address, x.items.present_position.size) \
        == (TICKS_PER_TURN, 132, 4)
    speed = ax.items.present_speed  # sign-magnitude: bit 10 is the direction (CW negative)
    assert (speed.decode([0x2C, 0x01]), speed.decode([0x2C, 0x05]), speed.encode(-300)) \
        == (300, -300, [0x2C, 0x05])
    current = MODELS["MX-64"].items.present_current  # 2048 = 0 A, 4.5 mA per unit
    assert (current.decode((2148).to_bytes(2, "little")), current.encode(-100)) \
        == (100, list((1948).to_bytes(2, "little")))
    assert {m.protocol for m in MODELS.values()} == {1.0, 2.0}
    assert [n for n, m in MODELS.items() if m.protocol == 1.0] == [
        "AX-12A", "AX-12W", "AX-18A", "RX-24F", "RX-28", "RX-64", "MX-12W", "MX-28", "MX-64", "MX-106"]
    assert [n for n, m in MODELS.items() if m.bulk_read and m.protocol == 1.0] == [
        "MX-12W", "MX-28", "MX-64", "MX-106"]


def test_hw_sim_imports_nothing_of_puppet():
    code = ("import sys, hw_sim, hw_sim.cli, hw_sim.rig_servos, hw_sim.control_table\n"
            "print(sorted(m for m in sys.modules if m == 'puppet' or m.startswith('puppet.')))\n")
    result = subprocess.run([sys.executable, "-P", "-c", code], capture_output=True, text=True, timeout=60)
    assert result.stdout.strip() == "[]", result.stderr


def test_every_model_is_served_and_read_by_the_bus():
    from puppet.bus import ServoReader

    servos = {k + 1: name for k, name in enumerate(SERVED_BY_THE_BUS)}
    with hw_sim.serve(servos) as bus:
        reader = ServoReader(bus.port, servos)
        try:
            report = reader.open()
            assert sorted(report.found) == sorted(servos)
            assert report.missing == []
            reading = reader.read_clean(timeout_s=30.0)
            assert reading.ticks.tolist() == [2048] * len(servos)
        finally:
            reader.close()


def test_every_model_is_served_and_read_through_the_sdk_at_its_own_addresses(open_sdk):
    # One bus per protocol; each servo pinged (model number) and read with the SDK of its
    # protocol where puppet's table says its items are: Present Position (the middle of its
    # range, held still), Present Temperature, Torque Enable; then turned on and sent a goal.
    for protocol in (1.0, 2.0):
        names = [name for name, m in MODELS.items() if m.protocol == protocol]
        servos = {k + 1: name for k, name in enumerate(names)}
        with hw_sim.serve(servos) as bus:
            sdk = open_sdk(bus.port, protocol=protocol)
            ph, port = sdk.packet, sdk.port
            read = {1: ph.read1ByteTxRx, 2: ph.read2ByteTxRx, 4: ph.read4ByteTxRx}
            write = {1: ph.write1ByteTxRx, 2: ph.write2ByteTxRx, 4: ph.write4ByteTxRx}
            for i, name in servos.items():
                items = MODELS[name].items
                assert ph.ping(port, i)[:2] == (MODELS[name].number, 0), name
                position = items.present_position
                assert read[position.size](port, i, position.address)[:2] == \
                    (MODELS[name].position_ticks // 2, 0), name
                temperature = items.present_temperature
                assert read[temperature.size](port, i, temperature.address)[:2] == \
                    (bus.servo(i).get("Present Temperature"), 0), name
                assert write[1](port, i, items.torque_enable.address, 1) == (0, 0), name
                goal = MODELS[name].position_ticks // 2 + 10
                assert write[items.goal_position.size](port, i, items.goal_position.address,
                                                        goal) == (0, 0), name
                assert read[1](port, i, items.torque_enable.address)[:2] == (1, 0), name
                assert bus.servo(i).get("Goal Position") == goal, name


def test_every_model_reports_a_load_in_its_own_current_unit(open_sdk, wait_until):
    # A load of half the motor's current (plus the idle current) reads back, through the SDK,
    # as that current in the model's Present Current unit, or as Present Load (0.1 % of the
    # motor's current) on a model that senses no current.
    servos = {k + 1: name for k, name in enumerate(SERVED_BY_THE_BUS)}
    with hw_sim.serve(servos) as bus:
        sdk = open_sdk(bus.port)
        expected = {}
        for i, name in servos.items():
            motor_ma = SIM_MODELS[name].spec.motor_current_ma
            assert sdk.write(i, 64, 1, 1) == 0
            bus.inject("load", i, current=motor_ma / 2)
            unit = MODELS[name].current_unit_ma
            drawn_ma = motor_ma / 2 + IDLE_CURRENT_MA
            expected[i] = drawn_ma / unit if unit else 1000 * drawn_ma / motor_ma

        def present(i: int) -> int:
            raw = sdk.read4(i, 124) >> 16 & 0xFFFF  # Present PWM (124) then item 126
            return raw - (1 << 16) if raw >= 1 << 15 else raw

        for i in servos:  # the current settles from below (first order): wait, then compare
            wait_until(lambda i=i: present(i) >= 0.97 * expected[i],
                       what=f"servo {i} ({servos[i]}) reads its load")
            assert present(i) == pytest.approx(expected[i], rel=0.03), servos[i]


def rig_file(tmp_path, calibration: str = ""):
    path = tmp_path / "mixed.toml"
    path.write_text(f'mesh = "x.glb"\n{calibration}'
                    '[[servo]]\nid = 3\nmodel = "XC330-T288"\njoint = "a"\naxis = "x"\n'
                    'zero_ticks = 1000\nlimits_deg = [-20, 60]\n'
                    '[[servo]]\nid = 7\nmodel = "XM540-W270"\njoint = "b"\naxis = "y"\nsign = -1\n'
                    'gear = 2.0\nzero_ticks = 3000\nlimits_deg = [-45, 45]\n'
                    '[[servo]]\nid = 20\nmodel = "2XL430-W250"\njoint = "c"\naxis = "z"\n'
                    'limits_deg = [10, 80]\n')
    return path


def test_a_rig_files_servos_are_read_device_side(tmp_path):
    path = rig_file(tmp_path, 'calibration = "cal.toml"\n')
    (tmp_path / "cal.toml").write_text("[zero_ticks]\n7 = 3100\n")
    assert read_rig_servos(path) == [
        RigServo(3, "XC330-T288", 1000, 1, 1.0, (-20.0, 60.0)),
        RigServo(7, "XM540-W270", 3100, -1, 2.0, (-45.0, 45.0)),
        RigServo(20, "2XL430-W250", 2048, 1, 1.0, (10.0, 80.0))]
    bad = tmp_path / "bad.toml"
    bad.write_text('[[servo]]\nid = 1\nmodel = "XC330-M999"\n')
    with pytest.raises(RigFileError, match=r"bad.toml: servo 1: hw_sim does not simulate model 'XC330-M999'"):
        read_rig_servos(bad)


def test_the_fitted_motion_swings_each_joint_across_its_own_range():
    """Centre ± 0.35 × span of each joint's limits over one period: a knee with limits [-5, 120]
    bends 13.75°..101.25°, never backwards; geared and reversed servos alike."""
    servos = [RigServo(3, "XC330-T288", 1000, 1, 1.0, (-20.0, 60.0)),
              RigServo(7, "XM540-W270", 3100, -1, 2.0, (-45.0, 45.0)),
              RigServo(20, "2XL430-W250", 2048, 1, 1.0, (10.0, 80.0)),
              RigServo(5, "XL430-W250", 500, -1, 1.0, (-5.0, 120.0))]
    motion = WithinLimits(servos)
    steps = 2400  # one period (2.4 s) in 1 ms steps
    for s in servos:
        angles = [s.sign * (motion.position(s.id, motion.period_s * k / steps) - s.zero_ticks) * 360
                  / TICKS_PER_TURN / s.gear for k in range(steps + 1)]
        low, high = s.limits_deg
        centre, half = (low + high) / 2, 0.35 * (high - low)
        assert low <= min(angles) and max(angles) <= high
        assert min(angles) == pytest.approx(centre - half, abs=1e-3)
        assert max(angles) == pytest.approx(centre + half, abs=1e-3)
    knee = [motion.position(5, motion.period_s * k / steps) for k in range(steps)]
    assert max(knee) < 500  # sign -1: a bent knee reads below its zero, never above (backwards)
    assert min(knee) == pytest.approx(500 - 101.25 * TICKS_PER_TURN / 360, abs=0.1)
    assert motion.position(99, 1.0) == 2048.0


def test_servos_option_parses_mixed_models():
    assert hw_sim.cli.parse_servos("1-3:XL330-M288,4-5:XL430-W250,7", "XM430-W350") == {
        1: "XL330-M288", 2: "XL330-M288", 3: "XL330-M288", 4: "XL430-W250", 5: "XL430-W250",
        7: "XM430-W350"}
    for bad, message in [("1-3:XL999", "unknown model 'XL999'"), ("1-3,2", "servo id 2 is given twice"),
                         ("5-2:XL430-W250", "backwards"), ("300", "outside 0..252")]:
        with pytest.raises(ValueError, match=message):
            hw_sim.cli.parse_servos(bad, "XL330-M288")


def served(open_sdk, short, port: str, expected: dict[int, int], ids) -> dict[int, int]:
    """{id: model number} of the ids in ``ids`` that answer a ping: those in ``expected`` are
    pinged with the patient deadline, the others (which must stay silent) with a short one."""
    sdk = open_sdk(port)
    out = {}
    for i in ids:
        if i in expected:
            number, result, _ = sdk.packet.ping(sdk.port, i)
        else:
            with short():
                number, result, _ = sdk.packet.ping(sdk.port, i)
        if result == 0:
            out[i] = number
    return out


def test_hw_sim_rig_serves_exactly_the_rigs_servos_within_limits(tmp_path, open_sdk, short,
                                                                  hw_sim_command):
    path = rig_file(tmp_path)
    sim = hw_sim_command("--rig", str(path))
    try:
        assert sim.port.startswith("/dev/pts/")
        expected = {3: 1220, 7: 1120, 20: 1090}
        assert served(open_sdk, short, sim.port, expected, range(1, 22)) == expected
        sdk = open_sdk(sim.port)
        servos = read_rig_servos(path)
        seen = {s.id: [] for s in servos}
        start = time.monotonic()
        while time.monotonic() - start < 2.6:  # one period of the motion (2.4 s), sampled
            for s in servos:
                ticks, result, _ = sdk.packet.read4ByteTxRx(sdk.port, s.id, PRESENT_POSITION)
                if result == 0:
                    ticks -= (1 << 32) if ticks >= 1 << 31 else 0
                    seen[s.id].append(s.sign * (ticks - s.zero_ticks) * 360 / TICKS_PER_TURN / s.gear)
            time.sleep(0.005)   # sampled, not spun: the period is the wait
        for s in servos:
            assert len(seen[s.id]) > 10
            assert s.limits_deg[0] - 0.2 <= min(seen[s.id]) and max(seen[s.id]) <= s.limits_deg[1] + 0.2
            assert max(seen[s.id]) - min(seen[s.id]) > 10  # it moves
    finally:
        err = sim.stop()
    assert "3 servos (3: XC330-T288; 7: XM540-W270; 20: 2XL430-W250)" in err
    assert "motion within the rig's limits" in err


def test_hw_sim_servos_serves_mixed_models_without_a_rig(open_sdk, short, hw_sim_command):
    sim = hw_sim_command("--servos", "1-3:XL330-M288,4-9:XL430-W250", "--motion", "wave")
    try:
        expected = {**{i: 1200 for i in (1, 2, 3)}, **{i: 1060 for i in range(4, 10)}}
        assert served(open_sdk, short, sim.port, expected, range(1, 11)) == expected
    finally:
        sim.stop()


def test_hw_sim_rig_errors_are_named(tmp_path, capsys):
    assert hw_sim.cli.main(["--rig", str(tmp_path / "none.toml")]) == 2
    assert f"hw-sim: --rig: {tmp_path / 'none.toml'}: cannot read rig file" in capsys.readouterr().err
    assert hw_sim.cli.main(["--rig", str(rig_file(tmp_path)), "--servos", "1-3"]) == 2
    assert "give --rig or --servos, not both" in capsys.readouterr().err
