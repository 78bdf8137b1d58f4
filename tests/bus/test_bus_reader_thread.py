"""ReaderThread on hw_sim: steady rate, newest-wins queue, commands, survival of faults."""

from __future__ import annotations

import time

import numpy as np

from puppet.bus import ReaderThread, ServoTimeout
from puppet.bus import health as hs
from puppet.servo_models import X_ITEMS


def test_steady_rate_independent_of_a_slow_consumer(sim, open_reader, wait_until):
    bus = sim(motion="wave")
    reader = open_reader(bus)
    with ReaderThread(reader, rate_hz=200, queue_len=4) as thread:
        t0, n0 = time.monotonic(), thread.reads
        got = []
        for _ in range(5):                     # a slow consumer: it takes one reading per 10 read
            pushed = thread.queue.pushed
            wait_until(lambda: thread.queue.pushed >= pushed + 10, what="ten more readings")
            got.append(thread.latest(timeout=60.0))
        elapsed, reads = time.monotonic() - t0, thread.reads - n0
    assert reads <= 200 * elapsed + 2          # never faster than its rate (a bound a slow machine keeps)
    assert all(r is not None for r in got)
    stamps = [r.t_ns for r in got]
    assert stamps == sorted(stamps)
    # Each reading handed out is the newest: the ones in between were dropped.
    assert thread.queue.dropped >= 5 * (10 - 4)
    assert not np.array_equal(got[0].ticks, got[-1].ticks)   # the wave moved


def test_back_to_back_reading_with_timing_model(sim, open_reader, wait_until):
    bus = sim(ids=range(1, 15), timing=True)
    reader = open_reader(bus, ids=range(1, 15))
    readings = []
    with ReaderThread(reader, rate_hz=None, queue_len=1 << 14) as thread:
        # The benchmark measures the real rate; here: 50 readings with every servo read.
        wait_until(lambda: readings.extend(thread.drain()) or sum(r.ok.all() for r in readings) >= 50,
                   what="50 full readings")
    assert all(h.state == hs.OK for h in reader.health.values())   # nothing booked failed


def test_thread_survives_unplug_and_runs_commands(sim, open_reader, wait_until):
    bus = sim(ids=(1, 2))
    bus.set_positions({1: 111, 2: 222})
    reader = open_reader(bus, ids=(1, 2))
    with ReaderThread(reader, rate_hz=300) as thread:
        bus.inject("unplug", duration_s=0.3)
        deadline = time.monotonic() + 60
        saw_down = saw_back = False
        while time.monotonic() < deadline and not saw_back:
            r = thread.latest(timeout=1.0)
            saw_down |= r is not None and not r.ok.any()
            saw_back = saw_down and r is not None and r.ok.all()
        assert saw_down and saw_back
        assert thread.alive
        def read_on_the_thread():  # one raw read: a loaded machine may time it out, try again
            try:
                return ("value", thread.call(reader.link.read, 1, X_ITEMS.return_delay_time).result(timeout=60))
            except ServoTimeout:
                return None

        assert wait_until(read_on_the_thread, what="a read on the reader's thread") == ("value", 0)
    assert not thread.alive
    assert reader.log.counts["port_restored"] == 1


def test_reader_thread_feeds_the_live_loop(sim, open_reader):
    """run_live takes a ReaderThread as well as a ReaderProcess (drain, latest, log)."""
    from puppet.loop import run_live

    class SolveCounter:
        iterations = 0
        solve_ns = 0
        iterate_ns = 0
        solver_iterations = 0
        renderer = None
        full = 0

        def solve(self, reading):
            self.full += bool(reading.ok.all())

    bus = sim(motion="wave")
    reader = open_reader(bus)
    counter = SolveCounter()
    with ReaderThread(reader, rate_hz=200.0, queue_len=256) as thread:
        summary = run_live(counter, thread, seconds=60, should_stop=lambda: counter.full >= 5)
    assert counter.full == 5
    assert summary.frames >= 5
    # a loaded machine may hand over readings with a held servo (its reply late): 'held_reading'
    assert {k: v for k, v in summary.faults.items() if k != "held_reading"} == dict(reader.log.counts)
