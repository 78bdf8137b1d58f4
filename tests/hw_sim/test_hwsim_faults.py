"""One test per fault kind: what the real dynamixel_sdk sees when it happens."""

from __future__ import annotations

import os
import termios
import threading
import time

import dynamixel_sdk as dxl
import pytest
import serial

import hw_sim
from hw_sim.faults import Fault

PRESENT_POSITION = 132


def _group(sdk, ids, addr=PRESENT_POSITION, size=4):
    group = dxl.GroupSyncRead(sdk.port, sdk.packet, addr, size)
    for i in ids:
        group.addParam(i)
    return group


def _wait_for(predicate, timeout_s=60.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


def _wait_past(end: float) -> None:
    """Wait until ``time.monotonic()`` passes ``end``: the end of a fault's window, on a clock
    behind the bus's (its t0 came first), so a ping after it finds the fault over (a ping in
    the window would wait out the SDK's whole ~2 s deadline)."""
    assert _wait_for(lambda: time.monotonic() > end)


def test_drop_times_out_and_fails_the_whole_group(bus, sdk, short):
    bus.inject("drop", ids=[2])
    with short():
        assert sdk.packet.ping(sdk.port, 2)[1] == dxl.COMM_RX_TIMEOUT
    assert sdk.packet.ping(sdk.port, 1)[1] == dxl.COMM_SUCCESS
    group = _group(sdk, [1, 2, 3])
    with short():
        assert group.txRxPacket() == dxl.COMM_RX_TIMEOUT
    assert group.isAvailable(1, PRESENT_POSITION, 4) is False  # even the servo that answered
    bus.clear_faults()
    assert group.txRxPacket() == dxl.COMM_SUCCESS


def test_bad_crc_is_rx_corrupt(bus, sdk):
    bus.inject("bad_crc", ids=1)
    # A complete packet with a wrong CRC is rejected at once (no timeout wait).
    assert sdk.packet.read4ByteTxRx(sdk.port, 1, PRESENT_POSITION)[1] == dxl.COMM_RX_CORRUPT
    assert _group(sdk, [1, 2]).fastSyncRead() == dxl.COMM_RX_CORRUPT


def test_truncated_reply_is_rx_corrupt(bus, sdk):
    bus.inject("truncate", ids=[3], keep=9)
    # The SDK waits out its whole deadline for the rest, then reports corruption.
    assert sdk.packet.read4ByteTxRx(sdk.port, 3, PRESENT_POSITION)[1] == dxl.COMM_RX_CORRUPT


def test_error_status_without_data_crashes_careless_reads(bus, sdk):
    bus.inject("error_status", ids=[2], error=1)
    _, result, error = sdk.packet.readTxRx(sdk.port, 2, PRESENT_POSITION, 4)
    assert (result, error) == (dxl.COMM_SUCCESS, 1)
    with pytest.raises(IndexError):
        sdk.packet.read4ByteTxRx(sdk.port, 2, PRESENT_POSITION)
    group = _group(sdk, [1, 2])
    assert group.txRxPacket() == dxl.COMM_SUCCESS  # the error byte is discarded by the SDK...
    with pytest.raises(IndexError):
        group.getData(2, PRESENT_POSITION, 4)  # ...and the missing data crashes getData


def test_power_cycle_reboots(bus, sdk, short):
    bus.set_positions({1: 4096 + 300})
    assert sdk.packet.read4ByteTxRx(sdk.port, 1, PRESENT_POSITION)[0] == 4396
    assert sdk.packet.write1ByteTxRx(sdk.port, 1, 65, 1) == (dxl.COMM_SUCCESS, 0)
    assert _wait_for(lambda: sdk.packet.read2ByteTxRx(sdk.port, 1, 120)[0] >= 500)
    tick_before = sdk.packet.read2ByteTxRx(sdk.port, 1, 120)[0]
    cycled = time.monotonic()
    bus.inject("power_cycle", ids=[1], duration_s=0.3)
    injected = time.monotonic()   # the window began before this: it ends before injected + 0.3
    with short():
        assert sdk.packet.ping(sdk.port, 1)[1] == dxl.COMM_RX_TIMEOUT
    _wait_past(injected + 0.3)
    assert _wait_for(lambda: sdk.packet.ping(sdk.port, 1)[1] == dxl.COMM_SUCCESS)
    assert sdk.packet.read4ByteTxRx(sdk.port, 1, PRESENT_POSITION)[0] == 300  # re-based
    assert sdk.packet.read1ByteTxRx(sdk.port, 1, 65)[0] == 0  # RAM defaults
    # Realtime Tick restarted: no more ms than since the cycle (else it would be past tick_before)
    assert sdk.packet.read2ByteTxRx(sdk.port, 1, 120)[0] <= (time.monotonic() - cycled) * 1000 + 1
    assert tick_before >= 500


def test_power_off_then_on(bus, sdk, short):
    bus.inject("power_off", ids=[3])
    assert bus.servo(3).powered is False
    with short():
        assert sdk.packet.ping(sdk.port, 3)[1] == dxl.COMM_RX_TIMEOUT
        assert _group(sdk, [1, 2, 3]).txRxPacket() == dxl.COMM_RX_TIMEOUT
    bus.inject("power_on", ids=[3])
    assert sdk.packet.ping(sdk.port, 3)[:2] == (1200, dxl.COMM_SUCCESS)


def test_unplug_while_reading_raises_serial_exception_and_leaves_port_busy(bus, sdk, monkeypatch):
    # A 5 s read window: the unplug below comes long before it closes, even on a loaded machine.
    monkeypatch.setattr(dxl.port_handler, "LATENCY_TIMER", 2500)
    bus.inject("drop")  # the SDK sits in its read loop...
    pings = bus.counts().get(0x01, 0)

    def unplug_once_pinged():  # ...once the ping is on the wire (not at a fixed time)
        _wait_for(lambda: bus.counts().get(0x01, 0) > pings)
        bus.inject("unplug")

    unplugger = threading.Thread(target=unplug_once_pinged, daemon=True)
    unplugger.start()
    # pyserial reports the vanished adapter from select() (readable, no data) or from read()
    # (EIO), depending on where the hang-up finds it.
    with pytest.raises(serial.SerialException, match="returned no data|Input/output error"):
        sdk.packet.ping(sdk.port, 1)  # ...when the adapter vanishes
    unplugger.join(timeout=60)
    assert sdk.port.is_using is True
    assert sdk.packet.ping(sdk.port, 1)[1] == dxl.COMM_PORT_BUSY
    assert bus.port is None and not os.path.exists(bus.link)
    bus.inject("replug")
    bus.clear_faults()
    sdk.close()
    assert os.path.exists(bus.link) and bus.port.startswith("/dev/pts/")
    again = dxl.PortHandler(bus.link)  # the stable path works again after replug
    assert again.openPort() and again.setBaudRate(1_000_000)
    assert sdk.packet.ping(again, 1)[:2] == (1200, dxl.COMM_SUCCESS)
    again.closePort()


def test_unplug_between_calls_fails_the_input_flush(bus, sdk):
    bus.inject("unplug", duration_s=0.2)
    with pytest.raises(termios.error):
        sdk.packet.ping(sdk.port, 1)  # clearPort() -> tcflush on a hung-up tty: EIO
    assert _wait_for(lambda: bus.port is not None)


def test_duplicate_id_collides(bus, sdk):
    bus.inject("duplicate_id", ids=[2], offset=100)
    # Identical ping replies collide into a valid one; differing data corrupts the reply.
    assert sdk.packet.ping(sdk.port, 2)[:2] == (1200, dxl.COMM_SUCCESS)
    assert sdk.packet.read4ByteTxRx(sdk.port, 2, PRESENT_POSITION)[1] == dxl.COMM_RX_CORRUPT
    bus.clear_faults()
    assert sdk.packet.read4ByteTxRx(sdk.port, 2, PRESENT_POSITION)[:2] == (2048, dxl.COMM_SUCCESS)


def test_duplicate_id_in_fast_sync_read_collides_crcs_too(bus, sdk):
    from hw_sim.codec import crc16

    bus.inject("duplicate_id", ids=[2], offset=100)
    bus.traffic()
    group = _group(sdk, [1, 2, 3])
    group.fastSyncRead()
    reply = b"".join(data for _, way, data in bus.traffic() if way == "tx")
    assert reply[:5] == bytes((0xFF, 0xFF, 0xFD, 0x00, 0xFE))
    body, seg = reply[8:], 4 + 4  # [ERR ID data(4) CRC(2)] per servo
    assert len(body) == 3 * seg
    first_crc = body[seg - 2:seg]
    assert first_crc == crc16(reply[:8 + seg - 2]).to_bytes(2, "little")  # servo 1: clean
    second = reply[:8 + 2 * seg - 2]
    # Servo 2 and its twin sent their own CRCs at once: the ANDed bytes no longer match.
    assert body[2 * seg - 2:2 * seg] != crc16(second).to_bytes(2, "little")
    # Servo 3 computes its CRC over what it heard, so the packet CRC the SDK checks is valid.
    assert body[3 * seg - 2:] == crc16(reply[:-2]).to_bytes(2, "little")


def test_hardware_error_sets_alert_until_reboot(bus, sdk):
    p, port = sdk.packet, sdk.port
    assert p.write1ByteTxRx(port, 1, 64, 1) == (dxl.COMM_SUCCESS, 0)
    bus.inject("hardware_error", ids=[1], error="overload")
    model, result, error = p.ping(port, 1)
    assert (model, result, error) == (1200, dxl.COMM_SUCCESS, 0x80)
    assert "Hardware error" in p.getRxPacketError(error)
    assert p.read1ByteTxRx(port, 1, 70) == (0x20, dxl.COMM_SUCCESS, 0x80)
    assert p.read1ByteTxRx(port, 1, 64) == (0, dxl.COMM_SUCCESS, 0x80)  # torque forced off
    assert p.write1ByteTxRx(port, 1, 64, 1) == (dxl.COMM_SUCCESS, 0x80)
    assert p.read1ByteTxRx(port, 1, 64)[0] == 0  # cannot re-enable while latched
    assert _group(sdk, [1, 2]).txRxPacket() == dxl.COMM_SUCCESS  # group reads hide the alert
    assert p.reboot(port, 1) == (dxl.COMM_SUCCESS, 0x80)
    assert p.read1ByteTxRx(port, 1, 70) == (0, dxl.COMM_SUCCESS, 0)


def test_overheating_raises_present_temperature(bus, sdk):
    bus.inject("hardware_error", ids=[2], error="overheating")
    temp, _, error = sdk.packet.read1ByteTxRx(sdk.port, 2, 146)
    assert error == 0x80 and temp > bus.servo(2).get("Temperature Limit")


def test_noise_jitters_present_position(bus, sdk):
    bus.inject("noise", ids=[1], amplitude=3)
    values = {sdk.packet.read4ByteTxRx(sdk.port, 1, PRESENT_POSITION)[0] for _ in range(40)}
    assert len(values) > 1
    assert all(2045 <= v <= 2051 for v in values)
    bus.clear_faults()
    assert {sdk.packet.read4ByteTxRx(sdk.port, 1, PRESENT_POSITION)[0] for _ in range(5)} == {2048}


def test_echo_is_seen_and_skipped_by_the_sdk(bus, sdk):
    bus.inject("echo")
    ping = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
    sdk.port.clearPort()
    sdk.port.writePort(ping)
    got = b""
    deadline = time.monotonic() + 2.0
    while len(got) < len(ping) + 14 and time.monotonic() < deadline:
        got += bytes(sdk.port.readPort(64))
    assert got[:len(ping)] == ping  # the host hears its own instruction first
    assert sdk.packet.ping(sdk.port, 1)[:2] == (1200, dxl.COMM_SUCCESS)
    assert _group(sdk, [1, 2, 3]).txRxPacket() == dxl.COMM_SUCCESS


def test_scheduled_fault_file(tmp_path, open_sdk, short):
    path = tmp_path / "faults.txt"
    path.write_text("# at kind\n0.0 drop ids=2 for=0.4\n0.0 noise ids=1-3 amplitude=0\n")
    with hw_sim.serve([1, 2, 3], faults=str(path)) as bus:
        served = time.monotonic()   # the bus's clock started before this
        sdk = open_sdk(bus.port)
        with short():
            assert sdk.packet.ping(sdk.port, 2)[1] == dxl.COMM_RX_TIMEOUT
        _wait_past(served + 0.4)
        assert _wait_for(lambda: sdk.packet.ping(sdk.port, 2)[1] == dxl.COMM_SUCCESS)


def test_fault_schedule_objects(open_sdk, short):
    schedule = [Fault.make("power_off", [1], start_s=0.0, duration_s=0.3)]
    with hw_sim.serve([1, 2], faults=schedule) as bus:
        served = time.monotonic()   # the bus's clock started before this
        sdk = open_sdk(bus.port)
        with short():
            assert _wait_for(lambda: sdk.packet.ping(sdk.port, 1)[1] == dxl.COMM_RX_TIMEOUT)
        _wait_past(served + 0.3)
        assert _wait_for(lambda: sdk.packet.ping(sdk.port, 1)[1] == dxl.COMM_SUCCESS)


def test_missing_servo_leaves_fast_sync_read_short(bus, sdk):
    bus.inject("drop", ids=[2])
    # The header promises 3 segments; one never comes: the SDK waits, then reports corruption.
    assert _group(sdk, [1, 2, 3]).fastSyncRead() == dxl.COMM_RX_CORRUPT


def test_echo_from_the_start(open_sdk):
    with hw_sim.serve([1, 2], echo=True) as bus:
        sdk = open_sdk(bus.port)
        bus.traffic()
        assert sdk.packet.read4ByteTxRx(sdk.port, 2, PRESENT_POSITION)[:2] == (2048, dxl.COMM_SUCCESS)
        traffic = bus.traffic()
        assert traffic[0][1] == "rx" and traffic[0][2][:4] == b"\xff\xff\xfd\x00"
