"""Protocol 1.0 on hw_sim, byte for byte: the real dynamixel_sdk ``PacketHandler(1.0)`` and an
independent Protocol 1.0 client written here (its own packets and checksum, not the SDK's) pass
the same transactions against AX / RX / MX servos; the XL-320's own table over
``PacketHandler(2.0)``; one protocol per bus; ``hw-sim --servos`` / ``--rig`` with Protocol 1.0
models."""

from __future__ import annotations

import time

import dynamixel_sdk as dxl
import pytest
import serial

import hw_sim
import hw_sim.cli
from hw_sim.errors import HwSimError

# Protocol 1.0 addresses (AX / RX / MX; e-manual control tables).
MODEL_NUMBER, FIRMWARE, CW_LIMIT, CCW_LIMIT = 0, 2, 6, 8
TORQUE, LED, GOAL, SPEED, POSITION, PRESENT_SPEED, LOAD = 24, 25, 30, 32, 36, 38, 40
TEMPERATURE, REGISTERED, MOVING, CURRENT = 43, 44, 46, 68
PING, READ, WRITE, REG_WRITE, ACTION, RESET, SYNC_WRITE, BULK_READ = (
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x83, 0x92)
VOLTAGE_ERR, ANGLE_ERR, OVERHEAT_ERR, RANGE_ERR = 0x01, 0x02, 0x04, 0x08
CHECKSUM_ERR, OVERLOAD_ERR, INSTRUCTION_ERR = 0x10, 0x20, 0x40
PATIENCE_S = 60.0

SERVOS = {1: "AX-12A", 2: "AX-18A", 3: "MX-28", 4: "MX-64", 5: "RX-28", 6: "MX-106"}
NUMBERS = {1: 12, 2: 18, 3: 29, 4: 310, 5: 28, 6: 320}
HELD = {1: 512, 2: 512, 3: 2048, 4: 2048, 5: 512, 6: 2048}
"""Present Position of each servo held at the middle of its range (the default motion)."""


class P1Client:
    """An independent Protocol 1.0 host: builds its own packets, computes its own checksum and
    parses status packets itself, on pyserial (no dynamixel_sdk)."""

    def __init__(self, port: str) -> None:
        self.serial = serial.Serial(port, 1_000_000, timeout=0)

    def close(self) -> None:
        self.serial.close()

    @staticmethod
    def checksum(body: bytes) -> int:
        return (~sum(body)) & 0xFF

    def packet(self, dxl_id: int, inst: int, params=(), checksum: int | None = None) -> bytes:
        body = bytes([dxl_id, len(params) + 2, inst, *params])
        return b"\xff\xff" + body + bytes([self.checksum(body) if checksum is None else checksum])

    def send(self, dxl_id: int, inst: int, params=(), checksum: int | None = None) -> None:
        self.serial.reset_input_buffer()
        self.serial.write(self.packet(dxl_id, inst, params, checksum))

    def _take(self, n: int, deadline: float) -> bytes:
        out = b""
        while len(out) < n:
            out += self.serial.read(n - len(out))
            if time.monotonic() > deadline:
                raise AssertionError(f"no status packet in {PATIENCE_S} s (got {out.hex(' ')})")
        return out

    def status(self) -> tuple[bytes, int, int, bytes]:
        """The next status packet: (its bytes, id, error byte, parameters); AssertionError on
        a wrong checksum or none within the patience."""
        deadline = time.monotonic() + PATIENCE_S
        while self._take(1, deadline) != b"\xff":
            pass
        head = self._take(1, deadline)
        while head == b"\xff":  # FF FF (FF ...): the id is the first byte that is not FF
            head = self._take(1, deadline)
        dxl_id = head[0]
        length = self._take(1, deadline)[0]
        rest = self._take(length, deadline)
        raw = b"\xff\xff" + bytes([dxl_id, length]) + rest
        assert rest[-1] == self.checksum(raw[2:-1]), f"checksum of {raw.hex(' ')}"
        return raw, dxl_id, rest[0], rest[1:-1]

    def transact(self, dxl_id: int, inst: int, params=()) -> tuple[int, bytes]:
        """(error byte, parameters) of the reply to one instruction."""
        self.send(dxl_id, inst, params)
        raw, got, error, data = self.status()
        assert got == dxl_id, raw.hex(" ")
        return error, data

    def read(self, dxl_id: int, addr: int, length: int) -> int:
        error, data = self.transact(dxl_id, READ, (addr, length))
        assert (error, len(data)) == (0, length)
        return int.from_bytes(data, "little")

    def no_reply_then_ping(self, dxl_id: int) -> None:
        """Proves the instruction just sent got no status: the next packet on the line is the
        reply to a ping of ``dxl_id`` (replies come in order)."""
        self.serial.write(self.packet(dxl_id, PING))
        raw, got, error, data = self.status()
        assert (got, error, data) == (dxl_id, 0, b""), raw.hex(" ")


@pytest.fixture
def p1_bus():
    with hw_sim.serve(SERVOS) as bus:
        yield bus


@pytest.fixture
def p1_sdk(p1_bus, open_sdk):
    return open_sdk(p1_bus.port, protocol=1.0)


@pytest.fixture
def client(p1_bus):
    c = P1Client(p1_bus.port)
    yield c
    c.close()


def _le(value: int, size: int = 2) -> list[int]:
    return list(value.to_bytes(size, "little"))


# ---- the real SDK ---------------------------------------------------------------------------
def test_sdk_pings_and_reads_every_model(p1_bus, p1_sdk, short):
    ph, port = p1_sdk.packet, p1_sdk.port
    # ping() is a PING and then a READ of the model number (address 0, 2 bytes).
    assert {i: ph.ping(port, i)[:3] for i in SERVOS} == {i: (n, 0, 0) for i, n in NUMBERS.items()}
    with short():
        assert ph.ping(port, 9)[1] == dxl.COMM_RX_TIMEOUT
    assert {i: ph.read2ByteTxRx(port, i, POSITION) for i in SERVOS} == {
        i: (HELD[i], 0, 0) for i in SERVOS}
    assert ph.read1ByteTxRx(port, 3, FIRMWARE)[1:] == (0, 0)
    assert ph.read2ByteTxRx(port, 1, CCW_LIMIT) == (1023, 0, 0)  # AX: 1024 positions
    assert ph.read2ByteTxRx(port, 3, CCW_LIMIT) == (4095, 0, 0)  # MX: 4096
    assert ph.read1ByteTxRx(port, 4, TEMPERATURE) == (p1_bus.servo(4).get("Present Temperature"), 0, 0)
    assert ph.read2ByteTxRx(port, 4, CURRENT) == (2048, 0, 0)  # MX-64: 2048 = 0 A, torque off


def test_sdk_writes_and_the_servo_moves(p1_bus, p1_sdk, wait_until):
    ph, port = p1_sdk.packet, p1_sdk.port
    assert ph.write1ByteTxRx(port, 1, TORQUE, 1) == (0, 0)
    assert ph.write2ByteTxRx(port, 1, SPEED, 200) == (0, 0)
    assert ph.write2ByteTxRx(port, 1, GOAL, 700) == (0, 0)
    wait_until(lambda: p1_sdk.read2(1, POSITION) == 700, what="AX-12A reaches its goal")
    assert p1_bus.servo(1).get("Present Position") == 700
    assert ph.write1ByteTxRx(port, 3, TORQUE, 1) == (0, 0)
    assert ph.write4ByteTxRx(port, 3, GOAL, 3000 | 100 << 16) == (0, 0)  # Goal and Moving Speed
    wait_until(lambda: p1_sdk.read2(3, POSITION) == 3000, what="MX-28 reaches its goal")
    assert ph.read1ByteTxRx(port, 3, MOVING) == (0, 0, 0)


def test_sdk_error_bits(p1_bus, p1_sdk):
    ph, port = p1_sdk.packet, p1_sdk.port
    # Protocol 1.0 writes the EEPROM with torque on (no lock but Lock (47)).
    assert ph.write1ByteTxRx(port, 1, TORQUE, 1) == (0, 0)
    assert ph.write2ByteTxRx(port, 1, CW_LIMIT, 100) == (0, 0)
    assert ph.write2ByteTxRx(port, 1, CCW_LIMIT, 900) == (0, 0)
    assert ph.write2ByteTxRx(port, 1, GOAL, 950) == (0, ANGLE_ERR)  # outside CW..CCW
    assert ph.write2ByteTxRx(port, 1, GOAL, 1100) == (0, RANGE_ERR)  # past 1023
    assert ph.write2ByteTxRx(port, 1, POSITION, 5) == (0, RANGE_ERR)  # read-only
    assert ph.getRxPacketError(ANGLE_ERR) == "[RxPacketError] Angle limit error!"
    p1_bus.inject("hardware_error", ids=[3], error="overheating")
    assert ph.read1ByteTxRx(port, 3, TORQUE) == (0, 0, OVERHEAT_ERR)  # in every status
    p1_bus.inject("hardware_error", ids=[4], error="overload")
    assert ph.write1ByteTxRx(port, 4, TORQUE, 1) == (0, OVERLOAD_ERR)  # and torque stays off
    assert ph.read1ByteTxRx(port, 4, TORQUE) == (0, 0, OVERLOAD_ERR)
    p1_bus.inject("hardware_error", ids=[5], error="input_voltage")
    assert ph.ping(port, 5) == (28, 0, VOLTAGE_ERR)
    assert ph.read1ByteTxRx(port, 6, TORQUE) == (0, 0, 0)  # the others are clean


def test_sdk_reg_write_and_action(p1_bus, p1_sdk):
    ph, port = p1_sdk.packet, p1_sdk.port
    assert ph.regWriteTxRx(port, 2, LED, 1, [1]) == (0, 0)
    assert ph.read1ByteTxRx(port, 2, REGISTERED) == (1, 0, 0)
    assert ph.read1ByteTxRx(port, 2, LED) == (0, 0, 0)  # registered, not done yet
    assert ph.action(port, 2) == dxl.COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 2, LED) == (1, 0, 0)
    assert ph.read1ByteTxRx(port, 2, REGISTERED) == (0, 0, 0)


def test_sdk_sync_write(p1_bus, p1_sdk):
    group = dxl.GroupSyncWrite(p1_sdk.port, p1_sdk.packet, LED, 1)
    for i in (1, 3, 6):
        assert group.addParam(i, [1]) is True
    assert group.txPacket() == dxl.COMM_SUCCESS
    assert {i: p1_sdk.packet.read1ByteTxRx(p1_sdk.port, i, LED)[0] for i in SERVOS} == {
        1: 1, 2: 0, 3: 1, 4: 0, 5: 0, 6: 1}


def test_sdk_bulk_read_on_mx(p1_bus, p1_sdk, short):
    ph, port = p1_sdk.packet, p1_sdk.port
    group = dxl.GroupBulkRead(port, ph)
    assert group.addParam(3, POSITION, 2) and group.addParam(4, POSITION, 4)
    assert group.addParam(6, TEMPERATURE, 1)
    # dynamixel_sdk 4.1.0's GroupBulkRead.txPacket passes Protocol 1.0's bulkReadTx an argument
    # it does not take (fast_option, since 3.8.2): the host sends with the handler's own
    # bulkReadTx and lets the group collect the replies.
    with pytest.raises(TypeError, match="positional argument"):
        group.txRxPacket()
    group.makeParam()
    assert group.param == [2, 3, POSITION, 4, 4, POSITION, 1, 6, TEMPERATURE]
    assert ph.bulkReadTx(port, group.param, len(group.param)) == dxl.COMM_SUCCESS
    assert group.rxPacket() == dxl.COMM_SUCCESS
    temperature = p1_bus.servo(6).get("Present Temperature")
    assert (group.getData(3, POSITION, 2), group.getData(4, POSITION, 2),
            group.getData(4, PRESENT_SPEED, 2), group.getData(6, TEMPERATURE, 1)) \
        == (2048, 2048, 0, temperature)
    # An AX has no Bulk Read: listed, it stays silent and the group fails.
    group.addParam(1, POSITION, 2)
    group.makeParam()
    assert ph.bulkReadTx(port, group.param, len(group.param)) == dxl.COMM_SUCCESS
    with short():
        assert group.rxPacket() == dxl.COMM_RX_TIMEOUT


# ---- the independent client -----------------------------------------------------------------
def test_independent_client_ping_and_read_byte_for_byte(client):
    client.send(1, PING)
    assert client.status()[0] == bytes.fromhex("ff ff 01 02 00 fc")
    client.send(1, READ, (POSITION, 2))  # 512 = 00 02, checksum ~(01+04+00+00+02)
    assert client.status()[0] == bytes.fromhex("ff ff 01 04 00 00 02 f8")
    assert {i: client.read(i, MODEL_NUMBER, 2) for i in SERVOS} == NUMBERS
    assert {i: client.read(i, POSITION, 2) for i in SERVOS} == HELD
    # The e-manual's example instruction (write 100 / 170 at 12) checks this client's checksum.
    assert client.packet(1, WRITE, (0x0C, 0x64, 0xAA)) == bytes.fromhex("ff ff 01 05 03 0c 64 aa dc")


def test_independent_client_writes_and_errors(p1_bus, client, wait_until):
    assert client.transact(3, WRITE, (TORQUE, 1)) == (0, b"")
    assert client.transact(3, WRITE, (GOAL, *_le(1000), *_le(300))) == (0, b"")
    wait_until(lambda: client.read(3, POSITION, 2) == 1000, what="MX-28 reaches its goal")
    assert client.transact(1, WRITE, (CW_LIMIT, *_le(100))) == (0, b"")
    assert client.transact(1, WRITE, (GOAL, *_le(50))) == (ANGLE_ERR, b"")
    assert client.transact(1, WRITE, (GOAL, *_le(2000))) == (RANGE_ERR, b"")
    client.send(1, WRITE, (LED, 1), checksum=0x00)  # a wrong checksum: answered, not done
    assert client.status()[1:3] == (1, CHECKSUM_ERR)
    assert client.read(1, LED, 1) == 0
    assert client.transact(1, 0x07, ()) == (INSTRUCTION_ERR, b"")  # no such instruction
    assert client.transact(2, ACTION, ()) == (INSTRUCTION_ERR, b"")  # nothing registered
    p1_bus.inject("hardware_error", ids=[2], error="overheating")
    assert client.transact(2, PING) == (OVERHEAT_ERR, b"")


def test_independent_client_reg_write_action_and_broadcast(client):
    assert client.transact(5, REG_WRITE, (LED, 1)) == (0, b"")
    assert client.read(5, REGISTERED, 1) == 1
    assert client.transact(5, ACTION) == (0, b"")
    assert (client.read(5, LED, 1), client.read(5, REGISTERED, 1)) == (1, 0)
    client.send(0xFE, WRITE, (LED, 1))  # a broadcast is done by all and answered by none
    client.no_reply_then_ping(1)
    assert {i: client.read(i, LED, 1) for i in SERVOS} == dict.fromkeys(SERVOS, 1)
    client.send(0xFE, PING)  # not even a ping
    client.no_reply_then_ping(2)


def test_independent_client_sync_write_and_bulk_read(client):
    client.send(0xFE, SYNC_WRITE, (SPEED, 2, 1, *_le(100), 3, *_le(200), 6, *_le(300)))
    client.no_reply_then_ping(4)
    assert [client.read(i, SPEED, 2) for i in (1, 3, 6, 4)] == [100, 200, 300, 0]
    client.send(0xFE, BULK_READ, (0x00, 2, 6, POSITION, 1, 3, TEMPERATURE, 2, 4, SPEED))
    replies = [client.status() for _ in range(3)]  # in the listed order
    assert [(raw[2], error, data) for raw, _, error, data in replies] == [
        (6, 0, bytes(_le(2048))), (3, 0, bytes([client.read(3, TEMPERATURE, 1)])),
        (4, 0, bytes(_le(0)))]
    assert replies[0][0] == bytes.fromhex("ff ff 06 04 00 00 08") + bytes(
        [client.checksum(bytes.fromhex("06 04 00 00 08"))])
    client.send(0xFE, BULK_READ, (0x00, 2, 1, POSITION))  # an AX has no Bulk Read: silence
    client.no_reply_then_ping(1)


def test_independent_client_reset(client):
    assert client.transact(1, WRITE, (CW_LIMIT, *_le(100), *_le(900))) == (0, b"")
    assert client.read(1, CW_LIMIT, 4) == 100 | 900 << 16
    assert client.transact(1, RESET) == (0, b"")  # answered, then every item to its default
    assert client.read(1, CW_LIMIT, 4) == 0 | 1023 << 16


# ---- one protocol per bus, the XL-320, the hw-sim command ----------------------------------
def test_a_bus_carries_one_protocol():
    with pytest.raises(HwSimError) as err:
        with hw_sim.serve({1: "AX-12A", 2: "XL430-W250", 3: "MX-28", 4: "XL-320"}):
            pass
    assert str(err.value) == ("one bus carries one protocol, these servos mix two: Protocol 1.0: "
                              "servos 1 (AX-12A), 3 (MX-28); Protocol 2.0: servos 2 (XL430-W250), "
                              "4 (XL-320)")
    with pytest.raises(HwSimError, match="servo 1: AX-12A: baud 4000000 is not one of"):
        with hw_sim.serve({1: "AX-12A"}, baud=4_000_000):
            pass


def test_a_protocol_2_packet_is_noise_to_protocol_1_servos(p1_bus, open_sdk, short):
    p2 = open_sdk(p1_bus.port)
    with short():
        assert p2.packet.ping(p2.port, 1)[1] == dxl.COMM_RX_TIMEOUT
    p1 = open_sdk(p1_bus.port, protocol=1.0)
    assert p1.packet.ping(p1.port, 1)[:2] == (12, dxl.COMM_SUCCESS)


def test_xl320_over_protocol_2(open_sdk, wait_until):
    with hw_sim.serve({1: "XL-320", 2: "XL-320", 3: "MX-28(2.0)"}) as bus:
        sdk = open_sdk(bus.port)
        ph, port = sdk.packet, sdk.port
        assert [ph.ping(port, i)[:3] for i in (1, 2, 3)] == [(350, 0, 0), (350, 0, 0), (30, 0, 0)]
        assert ph.read2ByteTxRx(port, 1, 37) == (512, 0, 0)  # Present Position 37, 2 bytes
        assert ph.read4ByteTxRx(port, 3, 132) == (2048, 0, 0)  # MX(2.0): the X-series table
        group = dxl.GroupSyncRead(port, ph, 37, 2)
        assert group.addParam(1) and group.addParam(2)
        assert group.txRxPacket() == dxl.COMM_SUCCESS
        assert (group.getData(1, 37, 2), group.getData(2, 37, 2)) == (512, 512)
        assert ph.write1ByteTxRx(port, 1, 24, 1) == (0, 0)
        assert ph.write2ByteTxRx(port, 1, 30, 800) == (0, 0)
        wait_until(lambda: sdk.read2(1, 37) == 800, what="XL-320 reaches its goal")
        assert ph.write1ByteTxRx(port, 1, 11, 1) == (0, 7)  # EEPROM with torque on: access error
        bus.inject("hardware_error", ids=[2], error="overheating")
        assert ph.read1ByteTxRx(port, 2, 50) == (0x04, 0, 0x80)  # Hardware Error Status 50, alert


def test_hw_sim_servos_serves_protocol_1(open_sdk, short, hw_sim_command):
    sim = hw_sim_command("--servos", "1-6:AX-12A,7-10:MX-28")
    try:
        sdk = open_sdk(sim.port, protocol=1.0)
        found = {}
        for i in range(1, 12):
            if i <= 10:
                number, result, _ = sdk.packet.ping(sdk.port, i)
            else:
                with short():
                    number, result, _ = sdk.packet.ping(sdk.port, i)
            if result == dxl.COMM_SUCCESS:
                found[i] = number
        assert found == {**dict.fromkeys(range(1, 7), 12), **dict.fromkeys(range(7, 11), 29)}
    finally:
        err = sim.stop()
    assert "10 servos (1-6: AX-12A; 7-10: MX-28)" in err


def test_hw_sim_rig_with_ax_servos_swings_inside_the_limits(tmp_path, open_sdk, hw_sim_command):
    rig = tmp_path / "ax.toml"
    rig.write_text('mesh = "x.glb"\n'
                   '[[servo]]\nid = 1\nmodel = "AX-12A"\njoint = "a"\naxis = "x"\n'
                   'zero_ticks = 512\nlimits_deg = [-40, 40]\n'
                   '[[servo]]\nid = 2\nmodel = "AX-18A"\njoint = "b"\naxis = "y"\nsign = -1\n'
                   'zero_ticks = 300\nlimits_deg = [0, 60]\n')
    sim = hw_sim_command("--rig", str(rig))
    try:
        sdk = open_sdk(sim.port, protocol=1.0)
        seen = {1: [], 2: []}
        zero, sign = {1: 512, 2: 300}, {1: 1, 2: -1}
        start = time.monotonic()
        while time.monotonic() - start < 2.6:  # one period of the motion (2.4 s), sampled
            for i in (1, 2):
                ticks, result, _ = sdk.packet.read2ByteTxRx(sdk.port, i, POSITION)
                if result == dxl.COMM_SUCCESS:
                    seen[i].append(sign[i] * (ticks - zero[i]) * 300 / 1024)  # degrees
            time.sleep(0.005)   # sampled, not spun: the period is the wait
        for i, (low, high) in {1: (-40, 40), 2: (0, 60)}.items():
            assert len(seen[i]) > 10
            assert low - 0.6 <= min(seen[i]) and max(seen[i]) <= high + 0.6  # a tick is 0.29°
            assert max(seen[i]) - min(seen[i]) > 10  # it moves
    finally:
        err = sim.stop()
    assert "2 servos (1: AX-12A; 2: AX-18A)" in err


def test_hw_sim_refuses_a_mixed_protocol_rig_naming_the_servos(tmp_path, capsys):
    rig = tmp_path / "mixed.toml"
    rig.write_text('[[servo]]\nid = 1\nmodel = "AX-12A"\n[[servo]]\nid = 2\nmodel = "XL430-W250"\n')
    assert hw_sim.cli.main(["--rig", str(rig)]) == 2
    assert ("hw-sim: one bus carries one protocol, these servos mix two: Protocol 1.0: servos "
            "1 (AX-12A); Protocol 2.0: servos 2 (XL430-W250)") in capsys.readouterr().err
    assert hw_sim.cli.main(["--servos", "1-2:AX-12A,3:XM430-W350"]) == 2
    assert "servos 1 (AX-12A), 2 (AX-12A); Protocol 2.0: servos 3 (XM430-W350)" in \
        capsys.readouterr().err
