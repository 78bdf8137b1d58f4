"""Every hw_sim fault kind on a Protocol 1.0 bus: what the real dynamixel_sdk
``PacketHandler(1.0)`` sees when it happens."""

from __future__ import annotations

import threading

import dynamixel_sdk as dxl
import pytest
import serial

import hw_sim
from hw_sim import codec1
from hw_sim.faults import KINDS

POSITION, TORQUE, LOAD, GOAL = 36, 24, 40, 30
SERVOS = {1: "AX-12A", 2: "MX-28", 3: "MX-64"}
COVERED = {"drop", "bad_crc", "truncate", "error_status", "power_cycle", "power_off", "power_on",
           "unplug", "replug", "duplicate_id", "hardware_error", "noise", "echo", "load", "late"}


@pytest.fixture
def p1(open_sdk):
    with hw_sim.serve(SERVOS) as bus:
        sdk = open_sdk(bus.port, protocol=1.0)
        yield bus, sdk.packet, sdk.port


def test_every_fault_kind_is_covered_here():
    assert set(KINDS) == COVERED


def test_drop_bad_crc_truncate_and_error_status(p1, short):
    bus, ph, port = p1
    bus.inject("drop", ids=[1])
    with short():
        assert ph.read2ByteTxRx(port, 1, POSITION)[1] == dxl.COMM_RX_TIMEOUT
    assert ph.read2ByteTxRx(port, 2, POSITION) == (2048, dxl.COMM_SUCCESS, 0)
    bus.clear_faults()
    bus.inject("bad_crc", ids=[2])  # a wrong checksum: rejected at once
    assert ph.read2ByteTxRx(port, 2, POSITION)[1] == dxl.COMM_RX_CORRUPT
    bus.clear_faults()
    bus.inject("truncate", ids=[3], keep=7)  # the SDK waits out its deadline for the rest
    assert ph.read2ByteTxRx(port, 3, POSITION)[1] == dxl.COMM_RX_CORRUPT
    bus.clear_faults()
    bus.inject("error_status", ids=[1], error=codec1.ERR_OVERLOAD)  # an error and no data
    _, result, error = ph.read1ByteTxRx(port, 1, POSITION)
    assert (result, error) == (dxl.COMM_SUCCESS, codec1.ERR_OVERLOAD)
    with pytest.raises(IndexError):  # the SDK's 2-byte read indexes the missing data
        ph.read2ByteTxRx(port, 1, POSITION)
    bus.clear_faults()
    assert ph.read2ByteTxRx(port, 1, POSITION) == (512, dxl.COMM_SUCCESS, 0)


def test_late_sends_the_whole_reply_after_the_sdk_deadline(open_sdk, short, wait_until):
    with hw_sim.serve(SERVOS, timing=True) as bus:
        sdk = open_sdk(bus.port, protocol=1.0)
        ph, port = sdk.packet, sdk.port
        bus.inject("late", ids=[1], ms=3000)  # far past a ~4.5 ms deadline, even on a busy host
        with short():
            assert ph.read2ByteTxRx(port, 1, POSITION)[1] == dxl.COMM_RX_TIMEOUT
        got = bytearray()
        wait_until(lambda: got.extend(port.ser.read(port.ser.in_waiting)) or len(got) >= 8,
                   what="the late reply")
        assert bytes(got[:5]) == bytes((0xFF, 0xFF, 1, 4, 0))  # servo 1's whole status, no error
        assert got[5] | got[6] << 8 == 512
        bus.clear_faults()


def test_power_off_on_and_cycle_reboot_the_servo(p1, short, wait_until):
    bus, ph, port = p1
    assert ph.write1ByteTxRx(port, 2, TORQUE, 1) == (0, 0)
    bus.inject("power_off", ids=[2])
    with short():
        assert ph.ping(port, 2)[1] == dxl.COMM_RX_TIMEOUT
    bus.inject("power_on", ids=[2])
    assert ph.read1ByteTxRx(port, 2, TORQUE) == (0, dxl.COMM_SUCCESS, 0)  # booted: torque off
    assert ph.write1ByteTxRx(port, 3, TORQUE, 1) == (0, 0)
    bus.inject("power_cycle", ids=[3], duration_s=0.2)
    wait_until(lambda: bus.servo(3).powered, what="servo 3 powered again")
    assert ph.read1ByteTxRx(port, 3, TORQUE) == (0, dxl.COMM_SUCCESS, 0)


def test_unplug_and_replug(p1, monkeypatch, wait_until):
    bus, ph, port = p1
    monkeypatch.setattr(dxl.port_handler, "LATENCY_TIMER", 2500)  # a 5 s read window
    bus.inject("drop")
    pings = bus.counts().get(0x01, 0)

    def unplug_once_pinged():
        wait_until(lambda: bus.counts().get(0x01, 0) > pings, what="the ping on the wire")
        bus.inject("unplug")

    unplugger = threading.Thread(target=unplug_once_pinged, daemon=True)
    unplugger.start()
    with pytest.raises(serial.SerialException, match="returned no data|Input/output error"):
        ph.ping(port, 1)
    unplugger.join(timeout=60)
    assert bus.port is None
    bus.inject("replug")
    bus.clear_faults()
    port.closePort()
    again = dxl.PortHandler(bus.link)
    assert again.openPort() and again.setBaudRate(1_000_000)
    assert ph.ping(again, 1)[:2] == (12, dxl.COMM_SUCCESS)
    again.closePort()


def test_duplicate_id_collides(p1):
    bus, ph, port = p1
    bus.inject("duplicate_id", ids=[1], offset=400)
    # Identical ping replies collide into a valid one; differing positions corrupt the reply.
    assert ph.ping(port, 1)[:2] == (12, dxl.COMM_SUCCESS)
    assert ph.read2ByteTxRx(port, 1, POSITION)[1] == dxl.COMM_RX_CORRUPT
    bus.clear_faults()
    assert ph.read2ByteTxRx(port, 1, POSITION) == (512, dxl.COMM_SUCCESS, 0)


def test_hardware_error_noise_and_load(p1, wait_until):
    bus, ph, port = p1
    assert ph.write1ByteTxRx(port, 2, TORQUE, 1) == (0, 0)
    bus.inject("hardware_error", ids=[2], error="overload")
    assert ph.read1ByteTxRx(port, 2, TORQUE) == (0, dxl.COMM_SUCCESS, codec1.ERR_OVERLOAD)
    assert bus.servo(2).hardware_error == 0x20
    bus.inject("noise", ids=[1], amplitude=3)
    seen = set()
    wait_until(lambda: seen.add(ph.read2ByteTxRx(port, 1, POSITION)[0]) or len(seen) > 2,
               what="noisy readings")
    assert seen <= set(range(509, 516))
    assert ph.write1ByteTxRx(port, 3, TORQUE, 1) == (0, 0)
    bus.inject("load", ids=[3], current=900)
    # Present Load, 0.1 % of the motor's current, bit 10 the direction; MX-64 Current: 4.5 mA.
    wait_until(lambda: ph.read2ByteTxRx(port, 3, 68)[0] > 2048 + 180, what="MX-64 current rises")
    load = ph.read2ByteTxRx(port, 3, LOAD)[0]
    assert 0 < load & 0x3FF < 1024


def test_echo_shows_the_instruction_before_the_status(p1):
    bus, ph, port = p1
    bus.inject("echo")
    bus.traffic()
    # Protocol 1.0 cannot tell an echoed instruction from a status: the SDK takes the echo of
    # its READ (ERR = the instruction code 2, the angle-limit bit) as the reply.
    value, result, error = ph.read2ByteTxRx(port, 1, POSITION)
    assert (result, error) == (dxl.COMM_SUCCESS, 0x02)
    assert value == POSITION | 2 << 8  # the READ's own parameters
    traffic = bus.traffic()
    assert [data for _, way, data in traffic if way == "rx"] == [
        codec1.packet(1, codec1.READ, bytes((POSITION, 2)))]  # what was echoed
    assert [data for _, way, data in traffic if way == "tx"] == [
        codec1.status_packet(1, 0, (512).to_bytes(2, "little"))]  # the servo's own status
    bus.clear_faults()
    assert ph.read2ByteTxRx(port, 1, POSITION) == (512, dxl.COMM_SUCCESS, 0)
