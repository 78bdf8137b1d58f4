"""Every Protocol 2.0 instruction through the real dynamixel_sdk on the simulated bus's pty."""

from __future__ import annotations

import time

import dynamixel_sdk as dxl
import pytest

import hw_sim
from hw_sim import codec

PRESENT_POSITION, GOAL_POSITION, LED, TORQUE = 132, 116, 65, 64


def _rx_tx(bus):
    """(host->bus bytes, bus->host bytes) seen since the last call."""
    traffic = bus.traffic()
    return (b"".join(d for _, k, d in traffic if k == "rx"),
            b"".join(d for _, k, d in traffic if k == "tx"))


def test_ping_bytes_match_emanual(bus, sdk):
    bus.traffic()
    model, result, error = sdk.packet.ping(sdk.port, 1)
    assert (model, result, error) == (1200, dxl.COMM_SUCCESS, 0)
    rx, tx = _rx_tx(bus)
    assert rx == bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
    assert tx == codec.status_packet(1, 0, bytes([0xB0, 0x04, 52]))


def test_ping_missing_id_times_out(bus, sdk, short):
    with short():
        _, result, _ = sdk.packet.ping(sdk.port, 9)
    assert result == dxl.COMM_RX_TIMEOUT


def test_broadcast_ping_every_servo_in_id_order(sdk):
    found, result = sdk.packet.broadcastPing(sdk.port)
    assert result == dxl.COMM_SUCCESS
    assert found == {1: [1200, 52], 2: [1200, 52], 3: [1200, 52]}


def test_read_and_access_error(bus, sdk):
    bus.set_positions({2: 3000})
    assert sdk.packet.read4ByteTxRx(sdk.port, 2, PRESENT_POSITION) == (3000, dxl.COMM_SUCCESS, 0)
    assert sdk.packet.read2ByteTxRx(sdk.port, 2, 0) == (1200, dxl.COMM_SUCCESS, 0)
    # Out of the table: Access Error with no data (the SDK slices the CRC as "data").
    _, result, error = sdk.packet.readTxRx(sdk.port, 2, 226, 4)
    assert (result, error) == (dxl.COMM_SUCCESS, codec.ERR_ACCESS)
    bus.traffic()
    sdk.packet.readTxRx(sdk.port, 2, 226, 4)
    assert _rx_tx(bus)[1] == codec.status_packet(2, codec.ERR_ACCESS)


def test_write_rules(bus, sdk):
    p, port = sdk.packet, sdk.port
    assert p.write4ByteTxRx(port, 1, 112, 77) == (dxl.COMM_SUCCESS, 0)
    assert bus.servo(1).get("Profile Velocity") == 77
    assert p.write1ByteTxRx(port, 1, 68, 3) == (dxl.COMM_SUCCESS, codec.ERR_DATA_RANGE)
    assert p.write2ByteTxRx(port, 1, GOAL_POSITION, 100) == (dxl.COMM_SUCCESS, codec.ERR_DATA_LENGTH)
    assert p.write4ByteTxRx(port, 1, PRESENT_POSITION, 1) == (dxl.COMM_SUCCESS, codec.ERR_ACCESS)
    assert p.write4ByteTxRx(port, 1, GOAL_POSITION, 5000) == (dxl.COMM_SUCCESS, codec.ERR_DATA_LIMIT)
    assert p.write1ByteTxRx(port, 1, 9, 0) == (dxl.COMM_SUCCESS, 0)  # EEPROM, torque off
    assert p.write1ByteTxRx(port, 1, TORQUE, 1) == (dxl.COMM_SUCCESS, 0)
    assert p.write1ByteTxRx(port, 1, 9, 10) == (dxl.COMM_SUCCESS, codec.ERR_ACCESS)  # locked
    assert bus.servo(1).get("Return Delay Time") == 0
    assert bus.servo(1).get("Profile Velocity") == 77


def test_broadcast_write_executes_without_reply(bus, sdk):
    bus.traffic()
    assert sdk.packet.write1ByteTxRx(sdk.port, dxl.BROADCAST_ID, LED, 1)[0] == dxl.COMM_SUCCESS
    rx, tx = _rx_tx(bus)
    assert tx == b""
    assert [bus.servo(i).get("LED") for i in (1, 2, 3)] == [1, 1, 1]


def test_reg_write_then_action(bus, sdk):
    p, port = sdk.packet, sdk.port
    assert p.regWriteTxRx(port, 2, LED, 1, [1]) == (dxl.COMM_SUCCESS, 0)
    assert (bus.servo(2).get("LED"), bus.servo(2).get("Registered Instruction")) == (0, 1)
    assert p.action(port, dxl.BROADCAST_ID) == dxl.COMM_SUCCESS
    assert (bus.servo(2).get("LED"), bus.servo(2).get("Registered Instruction")) == (1, 0)
    # Action with nothing registered: Instruction Error (the SDK never reads it; the wire shows it).
    bus.traffic()
    p.action(port, 2)
    deadline = time.monotonic() + 60.0
    tx = b""
    while not tx and time.monotonic() < deadline:
        tx = _rx_tx(bus)[1]
    assert tx == codec.status_packet(2, codec.ERR_INSTRUCTION)


def test_reboot_restores_ram_and_rebases(bus, sdk):
    p, port = sdk.packet, sdk.port
    bus.set_positions({1: 5000})
    assert p.read4ByteTxRx(port, 1, PRESENT_POSITION)[0] == 5000
    assert p.write1ByteTxRx(port, 1, LED, 1) == (dxl.COMM_SUCCESS, 0)
    assert _wait(lambda: p.read2ByteTxRx(port, 1, 120)[0] >= 50)
    tick_before = p.read2ByteTxRx(port, 1, 120)[0]
    rebooted = time.monotonic()
    assert p.reboot(port, 1) == (dxl.COMM_SUCCESS, 0)
    assert p.read4ByteTxRx(port, 1, PRESENT_POSITION)[0] == 5000 - 4096
    assert p.read1ByteTxRx(port, 1, LED)[0] == 0
    # the tick restarted: no more ms than since the reboot (else it would be past tick_before)
    assert p.read2ByteTxRx(port, 1, 120)[0] <= (time.monotonic() - rebooted) * 1000 + 1
    assert tick_before >= 50


def test_factory_reset_options(bus, sdk):
    p, port = sdk.packet, sdk.port
    assert p.write1ByteTxRx(port, 2, 9, 0) == (dxl.COMM_SUCCESS, 0)
    assert p.factoryReset(port, 2, 0x01) == (dxl.COMM_SUCCESS, 0)
    assert bus.servo(2).get("Return Delay Time") == 250
    assert bus.servo(2).get("ID") == 2
    assert p.factoryReset(port, 3, 0xFF) == (dxl.COMM_SUCCESS, 0)
    assert sorted(i for i in (1, 2, 3) if p.read1ByteTxRx(port, 1, 7)[1] == 0) == [1, 2, 3]
    assert bus.servo(1).get("ID") == 1  # servo 3 is now a second id 1


def test_clear_multi_turn(bus, sdk):
    bus.set_positions({3: -700})
    assert sdk.packet.read4ByteTxRx(sdk.port, 3, PRESENT_POSITION)[0] == (-700) & 0xFFFFFFFF
    assert sdk.packet.clearMultiTurn(sdk.port, 3) == (dxl.COMM_SUCCESS, 0)
    assert sdk.packet.read4ByteTxRx(sdk.port, 3, PRESENT_POSITION)[0] == 4096 - 700


def test_unknown_instruction_and_bad_crc(bus, sdk):
    tx = [0] * 10
    tx[dxl.protocol2_packet_handler.PKT_ID] = 1
    tx[dxl.protocol2_packet_handler.PKT_LENGTH_L] = 3
    tx[dxl.protocol2_packet_handler.PKT_INSTRUCTION] = 0x77
    _, result, error = sdk.packet.txRxPacket(sdk.port, tx)
    assert (result, error) == (dxl.COMM_SUCCESS, codec.ERR_INSTRUCTION)
    bus.traffic()
    sdk.port.clearPort()
    sdk.port.writePort(bytes.fromhex("FF FF FD 00 01 03 00 01 19 4F"))  # CRC off by one
    sdk.port.setPacketTimeout(20)
    _, result = sdk.packet.rxPacket(sdk.port, False)
    assert result == dxl.COMM_SUCCESS
    assert _rx_tx(bus)[1] == codec.status_packet(1, codec.ERR_CRC)


def _sync_read(sdk, ids, fast=False, addr=PRESENT_POSITION, size=4):
    group = dxl.GroupSyncRead(sdk.port, sdk.packet, addr, size)
    for i in ids:
        assert group.addParam(i)
    result = group.fastSyncRead() if fast else group.txRxPacket()
    return result, {i: group.getData(i, addr, size) for i in ids if group.isAvailable(i, addr, size)}


@pytest.mark.parametrize("fast", [False, True])
def test_sync_read_in_listed_order(bus, sdk, fast):
    bus.set_positions({1: 100, 2: 4200, 3: 0x00FDFFFF})  # bytes FF FF FD 00 need stuffing
    bus.traffic()
    result, data = _sync_read(sdk, [3, 1, 2], fast=fast)
    assert result == dxl.COMM_SUCCESS
    assert data == {3: 0x00FDFFFF, 1: 100, 2: 4200}
    tx = _rx_tx(bus)[1]
    if fast:
        assert tx[4] == 0xFE and tx.count(b"\xff\xff\xfd") == 2  # one packet; data unstuffed
    else:
        assert [tx[k + 4] for k in range(len(tx)) if tx[k:k + 4] == codec.HEADER] == [3, 1, 2]


def test_fast_sync_read_reply_is_emanual_example(open_sdk):
    with hw_sim.serve([3, 7, 4]) as bus:
        sdk = open_sdk(bus.port)
        bus.set_positions({3: 0xA6, 7: 0x081F, 4: 0x03FF})
        bus.traffic()
        result, data = _sync_read(sdk, [3, 7, 4], fast=True)
        assert (result, data) == (dxl.COMM_SUCCESS, {3: 0xA6, 7: 0x081F, 4: 0x03FF})
        assert _rx_tx(bus)[1] == bytes.fromhex(
            "FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA"
            " 00 04 FF 03 00 00 D1 9E")


def test_sync_write_no_reply(bus, sdk):
    group = dxl.GroupSyncWrite(sdk.port, sdk.packet, 112, 4)
    for i in (1, 2, 3):
        group.addParam(i, list((i * 10).to_bytes(4, "little")))
    bus.traffic()
    assert group.txPacket() == dxl.COMM_SUCCESS
    assert [bus.servo(i).get("Profile Velocity") for i in (1, 2, 3)] == [10, 20, 30]
    assert _rx_tx(bus)[1] == b""


@pytest.mark.parametrize("fast", [False, True])
def test_bulk_read(bus, sdk, fast):
    bus.set_positions({1: 1234})
    group = dxl.GroupBulkRead(sdk.port, sdk.packet)
    # ids and addresses chosen so the SDK's fast-bulk-read param.index bug does not bite
    assert group.addParam(1, PRESENT_POSITION, 4)
    assert group.addParam(2, 0, 2)
    assert group.addParam(3, 68, 1)
    result = group.fastBulkRead() if fast else group.txRxPacket()
    assert result == dxl.COMM_SUCCESS
    assert group.getData(1, PRESENT_POSITION, 4) == 1234
    assert group.getData(2, 0, 2) == 1200
    assert group.getData(3, 68, 1) == 2


def test_bulk_write(bus, sdk):
    group = dxl.GroupBulkWrite(sdk.port, sdk.packet)
    assert group.addParam(1, LED, 1, [1])
    assert group.addParam(3, 112, 4, list((55).to_bytes(4, "little")))
    bus.traffic()
    assert group.txPacket() == dxl.COMM_SUCCESS
    assert bus.servo(1).get("LED") == 1
    assert bus.servo(3).get("Profile Velocity") == 55
    assert bus.servo(2).get("LED") == 0
    assert _rx_tx(bus)[1] == b""


def test_status_return_level(bus, sdk, short):
    p, port = sdk.packet, sdk.port
    assert p.write1ByteTxRx(port, 2, 68, 1) == (dxl.COMM_SUCCESS, 0)
    with short():
        assert p.write1ByteTxRx(port, 2, LED, 1)[0] == dxl.COMM_RX_TIMEOUT
    assert bus.servo(2).get("LED") == 1  # executed, just silent
    assert p.read1ByteTxRx(port, 2, 68) == (1, dxl.COMM_SUCCESS, 0)
    assert p.write1ByteTxOnly(port, 2, 68, 0) == dxl.COMM_SUCCESS
    with short():
        assert p.read1ByteTxRx(port, 2, 68)[1] == dxl.COMM_RX_TIMEOUT
    assert p.ping(port, 2)[:2] == (1200, dxl.COMM_SUCCESS)


def test_indirect_address_mirrors_present_position(bus, sdk):
    p, port = sdk.packet, sdk.port
    bus.set_positions({1: 70000})
    for k in range(4):  # Indirect Address 1..4 -> Present Position bytes
        assert p.write2ByteTxRx(port, 1, 168 + 2 * k, PRESENT_POSITION + k) == (dxl.COMM_SUCCESS, 0)
    assert p.read4ByteTxRx(port, 1, 208) == (70000, dxl.COMM_SUCCESS, 0)


def test_partial_instruction_is_dropped_after_the_inter_byte_gap(bus, sdk):
    ping = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
    bus.traffic()
    sdk.port.writePort(ping[:6])  # a half packet, then silence longer than 1.5 ms
    # The gap is timed by the simulator from when it reads the bytes: wait until it has read the
    # half packet (a starved simulator could otherwise read it together with the ping).
    seen = []
    assert _wait(lambda: seen.extend(bus.traffic()) or any(k == "rx" for _, k, _ in seen))
    time.sleep(0.02)  # the silence itself (the inter-byte gap is 1.5 ms)
    assert sdk.packet.ping(sdk.port, 1)[:2] == (1200, dxl.COMM_SUCCESS)


def test_malformed_instructions(bus, sdk):
    p, port = sdk.packet, sdk.port
    tx = [0] * 12
    tx[dxl.protocol2_packet_handler.PKT_ID] = 1
    tx[dxl.protocol2_packet_handler.PKT_LENGTH_L] = 5  # a Read with 2 parameters, not 4
    tx[dxl.protocol2_packet_handler.PKT_INSTRUCTION] = codec.READ
    tx[dxl.protocol2_packet_handler.PKT_PARAMETER0] = PRESENT_POSITION
    _, result, error = p.txRxPacket(port, tx)
    assert (result, error) == (dxl.COMM_SUCCESS, codec.ERR_DATA_LENGTH)
    # A Read sent to the broadcast id is not executed and gets no reply.
    # (The SDK refuses to send one, so the bytes go out raw.)
    bus.traffic()
    port.writePort(codec.packet(dxl.BROADCAST_ID, codec.READ, bytes([PRESENT_POSITION, 0, 4, 0])))
    seen = []
    assert _wait(lambda: seen.extend(bus.traffic()) or any(k == "rx" for _, k, _ in seen))
    time.sleep(0.02)
    seen.extend(bus.traffic())
    assert [k for _, k, _ in seen] == ["rx"] and port.getBytesAvailable() == 0
    # Garbage and an impossible length are skipped; the next good packet is answered.
    port.writePort(bytes.fromhex("00 13 FF FF FD 00 01 FF FF 01"))
    assert p.ping(port, 2)[:2] == (1200, dxl.COMM_SUCCESS)


def test_secondary_id_executes_without_reply(bus, sdk):
    p, port = sdk.packet, sdk.port
    for i in (1, 2):
        assert p.write1ByteTxRx(port, i, 12, 100) == (dxl.COMM_SUCCESS, 0)
    bus.traffic()
    p.write1ByteTxOnly(port, 100, LED, 1)
    assert _wait(lambda: bus.servo(2).get("LED") == 1)
    assert [bus.servo(i).get("LED") for i in (1, 2, 3)] == [1, 1, 0]
    assert _rx_tx(bus)[1] == b""


def _wait(predicate, timeout_s=60.0):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True
