"""BusLink: the SDK's crash paths, shown on the raw SDK and absorbed by the link (hw_sim)."""

from __future__ import annotations

import dynamixel_sdk
import dynamixel_sdk.port_handler as sdk_port_handler
import pytest
import serial
import termios

from puppet.bus import BusLink, PortError, ServoCorrupt, ServoReader, ServoStatusError, ServoTimeout
from puppet.bus.latency import set_latency_assumption
from puppet.servo_models import X_ITEMS

PATIENT_MS = 255  # SDK latency assumption (its maximum) for calls that must succeed: ~0.5 s deadline


def test_latency_assumption_is_set_on_the_submodule():
    set_latency_assumption(3)
    assert sdk_port_handler.LATENCY_TIMER == 3
    with pytest.raises(ValueError, match="0 ms"):
        set_latency_assumption(0)


def test_error_status_without_data_is_a_typed_error_not_an_index_error(sim):
    bus = sim(ids=(1, 2))
    link = BusLink(bus.link, latency_ms=PATIENT_MS)
    link.open()
    bus.inject("error_status", ids=[2], error=0x07)
    # The bare SDK crashes on this reply ...
    with pytest.raises(IndexError):
        link.ph.read4ByteTxRx(link.port, 2, X_ITEMS.present_position.address)
    # ... the link names the servo, the instruction and the error.
    with pytest.raises(ServoStatusError) as info:
        link.read(2, X_ITEMS.present_position)
    assert info.value.ids == [2] and info.value.error & 0x7F == 0x07
    assert "access error" in str(info.value)
    group = link.sync_read([1, 2], X_ITEMS.present_position)
    assert list(group.values) == [1] and isinstance(group.failed[2], ServoStatusError)
    # A fast packet with a data-less segment comes up short: the whole packet fails (the
    # reader then reads each servo alone), as a typed error, not an IndexError.
    fast = link.fast_sync_read([1, 2], X_ITEMS.present_position)
    assert fast.values == {} and sorted(fast.failed) == [1, 2]
    assert all(isinstance(e, ServoCorrupt) for e in fast.failed.values())
    link.close()


def test_one_dead_servo_does_not_hide_the_others(sim):
    bus = sim(ids=(1, 2, 3))
    link = BusLink(bus.link, latency_ms=PATIENT_MS)
    link.open()
    bus.inject("drop", ids=[2])
    group = link.sync_read([1, 2, 3], X_ITEMS.present_position)
    assert 1 in group.values                   # answered before the failure: kept
    assert isinstance(group.failed[2], ServoTimeout) and group.failed[2].ids == [2]
    with pytest.raises(ServoTimeout) as info:
        link.ping(2)
    assert info.value.instruction == "ping"
    assert link.ping(3) == (1200, 52)
    bus.inject("truncate", ids=[3])
    with pytest.raises(ServoCorrupt):
        link.read(3, X_ITEMS.present_position)
    link.close()


def test_unplug_leaves_the_raw_sdk_busy_and_the_link_rebuilds(sim):
    bus = sim(ids=(1,))
    link = BusLink(bus.link, latency_ms=PATIENT_MS)
    link.open()
    raw = dynamixel_sdk.PortHandler(bus.link)
    raw.openPort()
    bus.inject("unplug")
    # On USB pyserial raises SerialException from read; on a pty tcflush raises termios.error.
    with pytest.raises((serial.SerialException, termios.error)):
        link.ph.ping(raw, 1)
    assert raw.is_using is True                 # the SDK's trap: every later call is "busy"
    with pytest.raises(PortError) as info:
        link.ping(1)
    assert info.value.port == bus.link and info.value.cause is not None
    with pytest.raises(PortError):
        link.rebuild()                         # the device is gone
    bus.inject("replug")
    link.rebuild()
    assert link.ping(1)[0] == 1200
    link.close()


def test_reader_accepts_an_open_port_handler(sim, read_until):
    bus = sim(ids=(1, 2))
    port = dynamixel_sdk.PortHandler(bus.port)
    assert port.openPort()
    reader = ServoReader(port, {1: "XL330-M288", 2: "XL330-M288"}, latency_ms=6)
    reader.open()
    assert reader.link.port is port
    read_until(reader, lambda r: r.ok.all(), what="a full reading")
    reader.close()


def test_old_firmware_falls_back_to_sync_read(sim, read_until):
    bus = sim(ids=(1, 2))
    bus.servo(2).set("Firmware Version", 40)   # X330 needs 46 for Fast Sync Read
    reader = ServoReader(bus.link, {1: "XL330-M288", 2: "XL330-M288"}, latency_ms=6)
    assert reader.open().read_mode == "sync_read"
    read_until(reader, lambda r: r.ok.all(), what="a full reading")
    reader.close()


def test_an_adapter_latency_timer_above_1_ms_is_set_to_1(tmp_path):
    from puppet.bus.latency import adapter_latency_ms, lower_latency_timer

    (tmp_path / "ttyUSB7").mkdir()
    timer = tmp_path / "ttyUSB7" / "latency_timer"
    timer.write_text("16\n")
    assert adapter_latency_ms("/dev/ttyUSB7", root=str(tmp_path)) == 16
    assert lower_latency_timer("/dev/ttyUSB7", root=str(tmp_path)) == (
        "port /dev/ttyUSB7: USB latency timer 16 -> 1 ms")
    assert timer.read_text() == "1"
    assert lower_latency_timer("/dev/ttyUSB7", root=str(tmp_path)) is None   # already 1 ms
    assert lower_latency_timer("/dev/pts/3", root=str(tmp_path)) is None     # no timer: a pty


def test_fast_sync_read_sends_the_sdks_request_and_reads_its_reply_past_an_echo(sim):
    # The link's own Fast Sync Read exchange puts on the line the very bytes the SDK's
    # syncReadTx sends, and finds the reply behind a half-duplex echo as the SDK's rxPacket does.
    bus = sim(ids=(1, 2, 3))
    bus.set_positions({1: 1000, 2: 2000, 3: 3000})
    link = BusLink(bus.link, latency_ms=PATIENT_MS)
    link.open()
    item = X_ITEMS.present_position
    bus.traffic()
    assert link.ph.syncReadTx(link.port, item.address, item.size, [1, 2, 3], 3, True) == 0
    sdk_rx, sdk_code = link.ph.rxPacket(link.port, True)
    sdk_sent = [data for _, way, data in bus.traffic() if way == "rx"]
    link.port.is_using = False
    group = link.fast_sync_read([1, 2, 3], item)
    ours = [data for _, way, data in bus.traffic() if way == "rx"]
    assert ours == sdk_sent and len(ours) == 1
    assert sdk_code == dynamixel_sdk.COMM_SUCCESS
    assert group.values == {1: 1000, 2: 2000, 3: 3000} and group.failed == {}
    bus.inject("echo")
    echoed = link.fast_sync_read([1, 2, 3], item)
    assert echoed.values == {1: 1000, 2: 2000, 3: 3000} and echoed.failed == {}
    link.close()


def test_the_links_crc16_is_the_sdks():
    # crc16 (two bytes a step, any start and end, continuing a CRC) against the SDK's updateCRC.
    import random

    from puppet.bus.codec import crc16

    ph = dynamixel_sdk.PacketHandler(2.0)
    rng = random.Random(28)
    for _ in range(300):
        data = [rng.randrange(256) for _ in range(rng.randrange(0, 160))]
        start, crc = rng.randrange(0, len(data) + 1), rng.randrange(1 << 16)
        assert crc16(data, crc, start, len(data)) == ph.updateCRC(crc, data[start:], len(data) - start)
        assert crc16(bytes(data), crc, start, len(data)) == crc16(data, crc, start, len(data))
