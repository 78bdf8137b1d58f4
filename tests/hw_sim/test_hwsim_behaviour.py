"""Servo behaviour in time: torque off follows the motion source past the wrap, torque on moves
under the profile, Realtime Tick / Moving / temperature / voltage, models, the timing model."""

from __future__ import annotations

import time

import dynamixel_sdk as dxl
import pytest

import hw_sim
from hw_sim.control_table import MODELS, get_model
from hw_sim.errors import UnknownModelError

PRESENT_POSITION = 132


def _pos(sdk, dxl_id):
    value, result, _ = sdk.packet.read4ByteTxRx(sdk.port, dxl_id, PRESENT_POSITION)
    assert result == dxl.COMM_SUCCESS
    return value - (1 << 32) if value >= 1 << 31 else value


def test_torque_off_counts_continuously_past_the_wrap(bus, sdk):
    for ticks in (4000, 4095, 4096, 4200, 9000, 100, 0, -1, -5000):
        bus.set_positions({1: ticks})
        assert _pos(sdk, 1) == ticks


def test_torque_on_moves_to_goal_under_profile(bus, sdk):
    p, port = sdk.packet, sdk.port
    assert p.write4ByteTxRx(port, 2, 112, 30) == (dxl.COMM_SUCCESS, 0)  # 6.9 rpm: ~2.2 s
    assert p.write4ByteTxRx(port, 2, 108, 50) == (dxl.COMM_SUCCESS, 0)
    assert p.write1ByteTxRx(port, 2, 64, 1) == (dxl.COMM_SUCCESS, 0)
    assert p.write4ByteTxRx(port, 2, 116, 3048) == (dxl.COMM_SUCCESS, 0)

    def mid_move():  # on its way, Moving set, Present Velocity positive
        return (2048 < _pos(sdk, 2) < 3048 and p.read1ByteTxRx(port, 2, 122)[0] == 1
                and p.read4ByteTxRx(port, 2, 128)[0] > 0)

    assert _wait(mid_move)
    assert _wait(lambda: _pos(sdk, 2) == 3048)
    assert _wait(lambda: p.read1ByteTxRx(port, 2, 122)[0] == 0)
    bus.set_positions({2: 100})  # the motion source is ignored while torque is on
    assert _pos(sdk, 2) == 3048


def test_torque_on_in_position_mode_rebases(bus, sdk):
    bus.set_positions({3: 4096 * 2 + 10})
    assert _pos(sdk, 3) == 8202
    assert sdk.packet.write1ByteTxRx(sdk.port, 3, 64, 1) == (dxl.COMM_SUCCESS, 0)
    assert _pos(sdk, 3) == 10


def test_realtime_tick_voltage_temperature(bus, sdk):
    p, port = sdk.packet, sdk.port
    start = time.monotonic()
    t1 = p.read2ByteTxRx(port, 1, 120)[0]
    time.sleep(0.05)                                  # at least this much servo time passes
    t2 = p.read2ByteTxRx(port, 1, 120)[0]
    elapsed_ms = (time.monotonic() - start) * 1000   # at most this much (a loaded machine: more)
    assert 49 <= (t2 - t1) % 32768 <= elapsed_ms + 1
    assert p.read2ByteTxRx(port, 1, 144)[0] == 50   # 5.0 V for the XL330
    assert 20 <= p.read1ByteTxRx(port, 1, 146)[0] <= 40


def test_homing_offset_adds_to_present_position(bus, sdk):
    bus.set_positions({1: 1000})
    assert sdk.packet.write4ByteTxRx(sdk.port, 1, 20, 500) == (dxl.COMM_SUCCESS, 0)
    assert _pos(sdk, 1) == 1500


def test_wave_moves_every_servo(open_sdk):
    with hw_sim.serve(range(1, 5), motion="wave") as bus:
        sdk = open_sdk(bus.port)
        first = [_pos(sdk, i) for i in range(1, 5)]
        second = []
        assert _wait(lambda: (second.clear() or second.extend(_pos(sdk, i) for i in range(1, 5))
                              or second != first))
        assert all(1400 <= v <= 2700 for v in first + second)
        assert len(set(first)) == 4  # phase differs along the chain


def test_mixed_models(open_sdk):
    with hw_sim.serve({1: "XL330-M288", 2: "XL430-W250", 3: "XM430-W350"}) as bus:
        sdk = open_sdk(bus.port)
        assert [sdk.packet.ping(sdk.port, i)[0] for i in (1, 2, 3)] == [1200, 1060, 1020]
        # XL430 has 28 indirect items at 168/224; XL330 has 20 at 168/208
        assert sdk.packet.read2ByteTxRx(sdk.port, 2, 168)[0] == 224
        assert sdk.packet.read2ByteTxRx(sdk.port, 1, 168)[0] == 208
        assert sdk.packet.read2ByteTxRx(sdk.port, 3, 32)[0] == 160
        assert bus.servo(2).model == "XL430-W250"


def test_control_tables_are_consistent():
    for model in MODELS.values():
        covered = set()
        for f in model.fields:
            span = set(range(f.addr, f.addr + f.size))
            assert not covered & span, (model.name, f.name)
            covered |= span
            assert f.addr + f.size <= model.size
            if f.lo is not None:
                assert f.lo <= f.default <= f.hi or f.name in ("Goal Current",), (model.name, f.name)
    assert get_model("XL430-W250").field("Present Load").addr == 126
    with pytest.raises(UnknownModelError, match="XL330-M288"):
        get_model("AX-99Z")


def test_timing_model_delays_replies(open_sdk):
    # 57600 baud, Return Delay 500 us: a 4-byte read is 14 + 15 bytes on the wire = 5.0 ms + 0.5 ms.
    with hw_sim.serve([1], timing=True, baud=57600) as bus:
        sdk = open_sdk(bus.port)
        assert sdk.port.setBaudRate(57600)
        times = []
        for _ in range(5):
            t = time.perf_counter()
            assert sdk.packet.read4ByteTxRx(sdk.port, 1, PRESENT_POSITION)[1] == dxl.COMM_SUCCESS
            times.append(time.perf_counter() - t)
        assert min(times) >= 0.0054


def test_bad_servo_arguments():
    with pytest.raises(hw_sim.HwSimError, match="253"):
        with hw_sim.serve([253]):
            pass
    with pytest.raises(UnknownModelError, match="XM999"):
        with hw_sim.serve([1], model="XM999"):
            pass


def test_sdk_can_close_and_reopen_the_port(bus, sdk):
    for _ in range(3):
        sdk.port.closePort()
        assert sdk.port.openPort() and sdk.port.setBaudRate(1_000_000)
        assert sdk.packet.ping(sdk.port, 3)[:2] == (1200, dxl.COMM_SUCCESS)


def test_backup_refused_while_torque_on(bus, sdk):
    p, port = sdk.packet, sdk.port
    tx = [0] * 15
    tx[dxl.protocol2_packet_handler.PKT_ID] = 1
    tx[dxl.protocol2_packet_handler.PKT_LENGTH_L] = 8
    tx[dxl.protocol2_packet_handler.PKT_INSTRUCTION] = 0x20
    tx[dxl.protocol2_packet_handler.PKT_PARAMETER0:dxl.protocol2_packet_handler.PKT_PARAMETER0 + 5] = [
        0x01, 0x43, 0x54, 0x52, 0x4C]
    assert p.txRxPacket(port, list(tx))[1:] == (dxl.COMM_SUCCESS, 0)
    assert p.write1ByteTxRx(port, 1, 64, 1) == (dxl.COMM_SUCCESS, 0)
    assert p.txRxPacket(port, list(tx))[1:] == (dxl.COMM_SUCCESS, 1)  # Result Fail


def test_thread_mode(open_sdk):
    with hw_sim.serve([1, 2], process=False) as bus:
        sdk = open_sdk(bus.port)
        bus.set_positions({2: 777})
        assert _pos(sdk, 2) == 777


def test_strict_baud_servos_hear_only_their_speed(open_sdk, short):
    with hw_sim.serve([1, 2], strict_baud=True) as bus:
        sdk = open_sdk(bus.port)  # opened at 1 Mbps, the bus speed
        p, port = sdk.packet, sdk.port
        assert p.ping(port, 1)[:2] == (1200, dxl.COMM_SUCCESS)
        assert port.setBaudRate(57600)
        with short():
            assert p.ping(port, 1)[1] == dxl.COMM_RX_TIMEOUT
        assert port.setBaudRate(1_000_000)
        assert p.write1ByteTxRx(port, 2, 8, 1) == (dxl.COMM_SUCCESS, 0)  # servo 2 -> 57600
        with short():
            assert p.ping(port, 2)[1] == dxl.COMM_RX_TIMEOUT
        assert port.setBaudRate(57600)
        assert p.ping(port, 2)[:2] == (1200, dxl.COMM_SUCCESS)


def test_velocity_mode_turns_continuously(bus, sdk):
    p, port = sdk.packet, sdk.port
    assert p.write1ByteTxRx(port, 1, 11, 1) == (dxl.COMM_SUCCESS, 0)  # velocity control
    assert p.write1ByteTxRx(port, 1, 64, 1) == (dxl.COMM_SUCCESS, 0)
    assert p.write4ByteTxRx(port, 1, 104, 400) == (dxl.COMM_SUCCESS, 0)  # 91.6 rpm ~ 6250 counts/s
    start = _pos(sdk, 1)
    assert _wait(lambda: _pos(sdk, 1) >= start + 4096)  # more than a turn: counts past 4095
    assert p.read4ByteTxRx(port, 1, 128)[0] == 400


def _wait(predicate, timeout_s=60.0):
    """Poll ``predicate`` until true (True) or ``timeout_s`` passes (False)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True
