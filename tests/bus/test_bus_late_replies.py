"""A reply that comes after its deadline (a busy host; the servo did answer) is a late reply,
never a servo fault: the reader logs ``late_reply`` and books nothing, and the live loop's
summary says so; a servo that truly does not answer stays a fault. hw_sim's ``late`` fault sends
the whole reply just past the SDK's deadline, through the real SDK on a pty."""

from __future__ import annotations

from puppet.bus import ReaderThread
from puppet.events import CONDITIONS, EVENT_KINDS, HELD_READING, describe_counts

MODEL = "XL330-M288"  # the servos of the `sim` fixture (tests/bus/conftest.py)

LATE_MS = 25.0
"""Just past the reads' deadline (~14 ms at the tests' 6 ms latency assumption)."""


def _faults(counts) -> dict:
    return {k: n for k, n in counts.items() if CONDITIONS[k].fault}


def _held_reading_events(reader, bus, n: int, read_until) -> list:
    seen = []
    read_until(reader, lambda r: reader.log.counts.get("late_reply", 0) >= n, what=f"{n} late replies",
               seen=seen)
    bus.clear_faults()
    return seen


def test_a_late_reply_is_logged_late_and_books_no_fault(sim, open_reader, read_until):
    bus = sim(timing=True)
    reader = open_reader(bus, stall_limit_s=600.0)  # only the line's proof may book a failure
    bus.inject("late", ids=[2], p=0.5, ms=LATE_MS)
    seen = _held_reading_events(reader, bus, 5, read_until)
    assert any(not r.ok.all() for r in seen)  # the late servo's value was held meanwhile
    # ... as late (Reading.late: the view paints no fault for it), never for a servo read fine
    assert any(r.late[1] for r in seen)
    assert all(not (r.late & r.ok).any() for r in seen)
    assert all(r.late[1] for r in seen if not r.ok[1]), [(r.ok, r.late) for r in seen]
    late = [e for e in reader.log.events if e.kind == "late_reply"]
    assert {2} <= {i for e in late for i in e.ids}
    assert _faults(reader.log.counts) == {}, reader.log.counts
    assert not EVENT_KINDS["late_reply"].fault


def test_a_servo_that_does_not_answer_is_still_a_fault(sim, open_reader, read_until):
    bus = sim(timing=True)
    reader = open_reader(bus)
    bus.inject("drop", ids=[3])
    seen = []
    read_until(reader, lambda r: reader.log.counts.get("servo_missing", 0) >= 1, what="servo 3 missing",
               seen=seen)
    assert not seen[-1].ok[2] and not seen[-1].late[2]  # held at fault, not late
    assert {3} == {i for e in reader.log.events if e.kind == "servo_missing" for i in e.ids}
    assert "servo_missing" in describe_counts(reader.log.counts).split(";")[0]


def test_the_live_summary_says_late_replies_not_a_fault(sim, open_reader):
    from puppet.loop import run_live

    class Counter:  # the loop's pipeline side, without a solve
        iterations = solve_ns = iterate_ns = solver_iterations = 0
        renderer = None

        def solve(self, reading):
            pass

    bus = sim(timing=True)
    reader = open_reader(bus, stall_limit_s=600.0)
    bus.inject("late", ids=[2], p=0.5, ms=LATE_MS)
    with ReaderThread(reader, rate_hz=200.0, queue_len=256) as thread:
        summary = run_live(Counter(), thread, seconds=120,
                           should_stop=lambda: reader.log.counts.get("late_reply", 0) >= 5)
    assert summary.faults.get("late_reply", 0) >= 5
    assert _faults(summary.faults) == {}, summary.faults
    line = summary.text().splitlines()[-1]
    assert line.startswith("faults seen: none; other events: "), line
    assert "late_reply" in line and "servo_not_ok" not in line
    assert set(summary.faults) <= set(CONDITIONS) and HELD_READING not in EVENT_KINDS


def test_a_bus_where_no_servo_of_the_map_answers_is_refused_after_one_wait(sim):
    """Protocol 2.0 servos in the map, AX-12A on the bus: nothing answers and nothing can
    witness the line, so the stall limit is waited once for the whole bus, not once per
    servo (15 servos x 5 s outran the reader's start: 'the reader process did not start'),
    and the setup fails naming the port, its speed and protocol and what to check."""
    import time

    import hw_sim
    import pytest

    from puppet.bus import ServoReader
    from puppet.bus.errors import ServoMissing

    ids = range(1, 9)
    with hw_sim.serve(servos={i: "AX-12A" for i in ids}) as bus:
        reader = ServoReader(bus.link, {i: "XL430-W250" for i in ids}, latency_ms=6.0,
                             stall_limit_s=1.0)
        start = time.monotonic()
        try:
            with pytest.raises(ServoMissing) as refused:
                reader.open()
        finally:
            reader.close()
        took = time.monotonic() - start
    assert refused.value.ids == list(ids)
    said = str(refused.value)
    assert f"no servo of the map answered on {bus.link} at 1000000 bit/s (Protocol 2.0" in said
    assert "puppet scan --port PORT --baud all" in said
    # one stall limit for the bus, then a ping each: well under one limit per servo
    assert took < len(ids) * 1.0, took


def test_a_reply_a_witness_showed_late_at_setup_never_makes_its_servo_missing(sim, open_reader):
    """Setup on a busy host: a servo's Status Return Level read misses its deadline, the ping
    that judges it shows the reply on its way (late) and reads it off the line; that verdict is
    kept (``ServoError.reply_late``). Judged again, the clean line would say 'silent' and the
    servo was booked missing ('servo_missing' in a plain `puppet demo` beside two busy loops)."""
    bus = sim(timing=True)
    bus.inject("late", ids=[2], p=0.5, ms=LATE_MS, duration_s=3.0)  # half its replies, at setup
    reader = open_reader(bus, stall_limit_s=600.0)  # only the line's proof may book a failure
    assert reader.report.missing == [] and 2 in reader.report.found
    assert "servo_missing" not in reader.log.counts, [
        (e.kind, e.ids, e.detail) for e in reader.log.events]
    assert reader.log.counts.get("late_reply", 0) >= 1  # the late replies were met, and said


def test_a_ping_witness_is_not_judged_by_an_earlier_pings_late_reply(sim):
    """A ping witness whose reply comes late (STALLED) leaves that reply on its way; a second
    ping witness of the same servo would take it for its own (a ping reply carries no sequence
    number), judge the line by it, and leave its own reply to answer a later 1-byte read (a
    Status Return Level 2 read as Torque Enable 2, as Hardware Error Status 0x02: a reboot sent
    for nothing, seen beside two busy loops). It says STALLED until a witness puts the line in
    order again."""
    import time

    from puppet.bus.link import LATE, SILENT, STALLED, BusLink

    def judged(ask):  # a loaded host may stall any witness: ask until one judges
        deadline = time.monotonic() + 60
        while (verdict := ask()) == STALLED and time.monotonic() < deadline:
            pass
        return verdict

    bus = sim(timing=True)
    link = BusLink(bus.port, latency_ms=6.0)
    link.open()
    try:
        assert judged(lambda: link.witness(2, ping=True)) in (LATE, SILENT)
        bus.inject("late", ids=[2], ms=200.0)
        assert link.witness(2, ping=True) == STALLED  # its reply is 200 ms away
        bus.clear_faults()
        time.sleep(0.4)  # the late reply has arrived: the stimulus, not a wait for a state
        assert link.witness(2, ping=True) == STALLED  # never judged by that reply
        assert judged(lambda: link.witness(1)) in (LATE, SILENT)  # a read orders the line ...
        assert judged(lambda: link.witness(2, ping=True)) in (LATE, SILENT)  # ... pings judge
    finally:
        link.close()


def test_replies_a_stalled_line_held_never_answer_the_next_read(sim):
    """The bus stalls (its process held: a host starved past every deadline) while the host
    asks one servo for the same 1-byte item again and again; no servo answered before, so each
    try settles the line with a wait and a flush, which prove nothing. The line moves just after
    the last flush: the held replies come one after another (57600 bit/s: ~2.5 ms each), the
    first answers that try, and the others must not answer the next 1-byte read (a Status
    Return Level of 2 read as Hardware Error Status 0x02: a false 'hardware error latched',
    seen with hw_sim starved on a loaded machine)."""
    import os
    import signal

    import pytest

    from puppet.bus.errors import ServoTimeout
    from puppet.bus.link import BusLink
    from puppet.servo_models import model_named

    baud = 57_600
    bus = sim(timing=True, baud=baud)
    items = model_named(MODEL).items
    link = BusLink(bus.port, baud=baud, latency_ms=6)
    link.open()
    server = bus._worker.pid

    def read(item):  # as every caller does, an instruction the line left unproven again
        for _ in range(100):
            try:
                return link.read(1, item)
            except ServoTimeout as err:
                if not err.line_stalled:
                    raise
        raise AssertionError("the line stayed stalled")

    os.kill(server, signal.SIGSTOP)
    try:
        for _ in range(8):
            with pytest.raises(ServoTimeout):
                link.read(1, items.status_return_level)
        flush = link.port.ser.reset_input_buffer

        def flush_then_move():  # the held line moves just after the host's flush
            link.port.ser.reset_input_buffer = flush
            flush()
            os.kill(server, signal.SIGCONT)

        link.port.ser.reset_input_buffer = flush_then_move
        assert read(items.status_return_level) == 2
    finally:
        os.kill(server, signal.SIGCONT)
    assert read(items.hardware_error_status) == 0
    assert read(items.status_return_level) == 2
    link.close()
