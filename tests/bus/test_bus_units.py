"""Unit tests of the bus pieces that need no bus: items, unwrapping, errors, the queue."""

from __future__ import annotations

import pickle
import threading

import numpy as np
import pytest

from puppet.bus import Reading, ReaderDied, ReaderThread
from puppet import servo_models
from puppet.bus.codec import describe_status_error
from puppet.bus.errors import PortError, ServoStatusError, ServoTimeout
from puppet.bus.reader_thread import LatestQueue
from puppet.bus.unwrap import TurnUnwrapper, nearest_turn_offset
from puppet.events import EventLog


def test_item_round_trips_signed_present_position():
    position = servo_models.X_ITEMS.present_position
    for value in (-5, 0, 4095, 4096, -70000, 2**31 - 1, -(2**31)):
        assert position.decode(position.encode(value)) == value
    # The SDK hands back unsigned; -5 arrives as 4294967291.
    assert position.decode(list((4294967291).to_bytes(4, "little"))) == -5
    assert servo_models.X_ITEMS.realtime_tick.decode([0xFF, 0x7F]) == 32767


def test_models_are_data_with_their_numbers():
    numbers = {m.name: m.number for m in servo_models.MODELS.values()}
    assert {name: numbers[name] for name in ("XL330-M288", "XL430-W250", "XM430-W350")} == {
        "XL330-M288": 1200, "XL430-W250": 1060, "XM430-W350": 1020}
    assert len(set(numbers.values())) == len(numbers)  # one model per number
    with pytest.raises(ValueError, match="XL320"):
        servo_models.model_named("XL320")


def test_error_descriptions_name_the_bits():
    assert servo_models.describe_hardware_error(0b110100) == "overheating, electrical shock, overload"
    assert servo_models.describe_hardware_error(0) == "none"
    assert describe_status_error(0x80) == "alert (hardware error latched)"
    assert describe_status_error(0x87) == "alert (hardware error latched), access error"


def test_typed_errors_carry_ids_and_instruction():
    exc = ServoTimeout([7, 3], "sync_read", "no status")
    assert exc.ids == [3, 7]
    assert exc.instruction == "sync_read"
    assert str(exc) == "timeout: servos [3, 7] during sync_read: no status"
    status = ServoStatusError([2], "read", "access error", error=0x07)
    back = pickle.loads(pickle.dumps(status))
    assert (back.ids, back.error, str(back)) == ([2], 0x07, str(status))
    lost = PortError("/dev/ttyUSB0", "lost during sync_read", OSError(5, "Input/output error"))
    back = pickle.loads(pickle.dumps(lost))         # errors cross to the reader process's parent
    assert (back.port, back.reason) == ("/dev/ttyUSB0", "lost during sync_read")
    assert "Input/output error" in back.cause_text


def test_nearest_turn_offset():
    assert nearest_turn_offset(100, 100) == 0
    assert nearest_turn_offset(904, 5000) == 4096
    assert nearest_turn_offset(4086, -10) == -4096
    assert nearest_turn_offset(10, 3 * 4096 + 12) == 3 * 4096


def test_unwrapper_keeps_counts_continuous_across_a_rebase():
    u = TurnUnwrapper()
    assert u.accept(4090) == (4090, False)
    assert u.accept(4100) == (4100, False)      # torque off: the servo itself counts past 4095
    u = TurnUnwrapper()
    u.accept(5000)
    assert u.accept(904 + 3) == (5003, True)    # reboot re-based 5000 -> 904; +3 of motion
    assert u.offset == 4096
    assert u.accept(910) == (5006, False)       # later readings keep the offset
    assert u.to_raw(5006) == 910
    u2 = TurnUnwrapper()
    u2.accept(-10)
    assert u2.accept(4086) == (-10, True)


def test_unwrapper_leaves_small_motion_and_out_of_range_values_alone():
    u = TurnUnwrapper()
    u.accept(2000)
    assert u.accept(3000) == (3000, False)      # under half a turn: plain motion
    assert u.accept(8000) == (8000, False)      # raw outside 0..4095 is never a re-base
    assert u.offset == 0


def test_latest_queue_newest_wins_and_counts_drops():
    q = LatestQueue(3)
    for i in range(5):
        q.put(i)
    assert len(q) == 3
    assert q.dropped == 2
    assert q.latest(timeout=0) == 4
    assert q.dropped == 4                      # 2 and 3 were never handed out
    assert q.latest(timeout=0.01) is None
    for i in range(2):
        q.put(i)
    assert q.drain() == [0, 1]


def test_latest_queue_wakes_a_waiting_consumer():
    q = LatestQueue(2)
    got = []
    t = threading.Thread(target=lambda: got.append(q.latest(timeout=5)))
    t.start()
    q.put("x")
    t.join(5)
    assert got == ["x"]


def test_reader_rejects_a_bad_map():
    from puppet.bus import ServoReader
    with pytest.raises(ValueError, match="XL999"):
        ServoReader("/dev/null", {1: "XL999"})
    with pytest.raises(ValueError, match="300"):
        ServoReader("/dev/null", {300: "XL330-M288"})
    with pytest.raises(ValueError, match=r"driven servos \[9\] are not in the servo map"):
        ServoReader("/dev/null", {1: "XL330-M288"}, driven=[9])


class _ScriptedReader:
    """Stands in for ServoReader to test the thread's own rules: read() follows a script."""

    def __init__(self, script):
        self.script = list(script)
        self.log = EventLog()

    def read(self):
        step = self.script.pop(0) if self.script else "ok"
        if isinstance(step, BaseException):
            raise step
        return Reading(0, np.array([1]), np.array([len(self.script)], np.int32), np.array([True]))


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_reader_thread_absorbs_bus_errors_and_reports_bugs():
    """A bus error from read() is logged and the loop goes on; a bug stops the thread and
    reaches the consumer as ReaderDied (the thread re-raises it: the traceback is printed)."""
    thread = ReaderThread(_ScriptedReader([ServoTimeout([4], "sync_read"), "ok"]), rate_hz=1000).start()
    assert thread.latest(timeout=2) is not None
    assert thread.bus_errors == 1 and thread.alive
    assert thread.reader.log.counts == {"read_error": 1}
    thread.stop()
    broken = ReaderThread(_ScriptedReader([KeyError("bug")]), rate_hz=1000).start()
    broken._thread.join(2)
    assert not broken.alive
    with pytest.raises(ReaderDied) as info:
        broken.latest(timeout=0.1)
    assert isinstance(info.value.__cause__, KeyError)
