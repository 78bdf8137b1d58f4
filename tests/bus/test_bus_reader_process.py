"""ReaderProcess: the bus read in a child process, readings through a shared ring."""

import os
import signal
import threading
import time

import numpy as np
import pytest

import hw_sim
from puppet.bus.reader_process import ReaderProcess, ReaderProcessError

MODELS = {1: "XL330-M288", 2: "XL430-W250", 3: "XM430-W350"}


def test_readings_arrive_in_order_with_the_simulated_positions(wait_until):
    with hw_sim.serve(MODELS) as bus:
        bus.set_positions({1: 100, 2: 5000, 3: -300})
        with ReaderProcess(bus.port, MODELS, rate_hz=300.0) as source:
            assert set(source.report.found) == set(MODELS)
            batch = []
            wait_until(lambda: batch.extend(source.drain()) or (len(batch) > 20 and batch[-1].ok.all()),
                       what="20 readings, the last one full")
    assert len(batch) > 20
    t = np.array([r.t_ns for r in batch])
    assert (np.diff(t) > 0).all()
    assert batch[-1].ticks.tolist() == [100, 5000, -300]
    assert batch[-1].ok.all()
    assert batch[-1].ids.tolist() == [1, 2, 3]


def test_a_consumer_that_falls_behind_loses_only_the_oldest(wait_until):
    with hw_sim.serve(MODELS, motion="wave") as bus:
        with ReaderProcess(bus.port, MODELS, rate_hz=400.0, slots=16) as source:
            wait_until(lambda: source.produced > 40, what="more readings than the ring holds")
            batch = source.drain()
            assert source.dropped > 0
            assert 1 <= len(batch) <= 16
            newest = source.latest(timeout=1.0)
    assert newest is not None
    assert newest.t_ns > batch[-1].t_ns


def test_bus_events_come_back_from_the_child(wait_until):
    with hw_sim.serve(MODELS) as bus:
        with ReaderProcess(bus.port, MODELS, rate_hz=300.0) as source:
            bus.inject("drop", ids=[2])
            batch = []
            wait_until(lambda: batch.extend(source.drain()) or source.log.counts.get("servo_failed"),
                       what="servo_failed from the child")
            bus.clear_faults()
            wait_until(lambda: batch.extend(source.drain()) or (batch and batch[-1].ok.all()),
                       what="a full reading after the fault")
    assert any(not r.ok[1] for r in batch)
    assert batch[-1].ok.all()
    assert source.log.counts.get("servo_failed", 0) >= 1
    assert any(2 in e.ids for e in source.log.events)


def test_a_missing_port_is_a_clear_error():
    source = ReaderProcess("/dev/puppet-no-such-port", MODELS)
    with pytest.raises(ReaderProcessError, match="/dev/puppet-no-such-port"):
        source.start(timeout_s=20.0)
    assert not source.alive


def test_a_requested_reading_comes_before_the_next_scheduled_one(wait_until):
    # One scheduled reading per 1000 s: only the requests can bring the readings after the first.
    with hw_sim.serve(MODELS) as bus:
        with ReaderProcess(bus.port, MODELS, rate_hz=0.001) as source:
            first = source.latest(timeout=30.0)
            assert first is not None
            for _ in range(3):
                asked_ns = time.monotonic_ns()
                source.request_reading()
                fresh = wait_until(lambda: next((r for r in source.drain() if r.t_ns >= asked_ns), None),
                                   timeout=30, what="the requested reading")
                assert fresh.ids.tolist() == list(MODELS)  # a whole reading (a starved line may flag a servo)


def test_a_request_to_a_dead_reader_is_reported_by_drain():
    with hw_sim.serve(MODELS) as bus:
        source = ReaderProcess(bus.port, MODELS, rate_hz=300.0)
        source.start()
        try:
            source._proc.kill()
            source._proc.join()
            source.request_reading()  # the pipe is broken: no error here
            with pytest.raises(ReaderProcessError, match="stopped"):
                while True:
                    source.drain()
        finally:
            source.stop()


def test_a_reader_killed_before_its_stop_is_named_by_the_stop():
    """A consumer that stops before it drains again (a key session whose input ended just after
    the kill) still learns that the child died; a plain stop names nothing."""
    with hw_sim.serve(MODELS) as bus:
        killed = ReaderProcess(bus.port, MODELS, rate_hz=300.0)
        killed.start()
        killed._proc.kill()
        killed._proc.join()
        killed.stop()
        assert killed.died == f"port {bus.port}: the reader process stopped (killed by SIGKILL)"
        asked = ReaderProcess(bus.port, MODELS, rate_hz=300.0)
        asked.start()
        asked.stop()
        assert asked.died is None


def test_a_reader_killed_as_its_stop_begins_is_named_by_the_stop(wait_until):
    """A SIGKILL that a busy host carries out only after the stop began (the child still
    alive when asked: a key session whose input closed just after the kill, in CI) is named
    too; the stop's own kill of a child that would not stop is not."""
    with hw_sim.serve(MODELS) as bus:
        source = ReaderProcess(bus.port, MODELS, rate_hz=300.0)
        source.start()
        pid = source._proc.pid
        os.kill(pid, signal.SIGSTOP)  # alive and not running: a starved child
        stopping = threading.Thread(target=source.stop, kwargs={"timeout": 120.0})
        stopping.start()
        wait_until(lambda: source._stop_word[0] == 1, what="the stop under way")
        os.kill(pid, signal.SIGKILL)
        stopping.join()
        assert source.died == f"port {bus.port}: the reader process stopped (killed by SIGKILL)"
        stuck = ReaderProcess(bus.port, MODELS, rate_hz=300.0)
        stuck.start()
        os.kill(stuck._proc.pid, signal.SIGSTOP)  # never answers the stop: killed by it
        stuck.stop(timeout=0.5)
        assert stuck.died is None
