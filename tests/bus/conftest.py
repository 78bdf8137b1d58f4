"""Fixtures for the bus tests: a simulated bus (hw_sim) and a ServoReader on its port."""

from __future__ import annotations

import time
from collections.abc import Callable

import dynamixel_sdk.port_handler as sdk_port_handler
import pytest

import hw_sim
from puppet.bus import Reading, ServoReader

MODEL = "XL330-M288"
LATENCY_MS = 6  # a failed read costs ~14 ms; the simulator may wait that long for a CPU


@pytest.fixture(autouse=True)
def _restore_latency_timer():
    """The SDK's LATENCY_TIMER is a process-wide module global: put it back after each test."""
    saved = sdk_port_handler.LATENCY_TIMER
    yield
    sdk_port_handler.LATENCY_TIMER = saved


@pytest.fixture
def sim():
    """Factory: sim(ids=(1, 2, 3, 4), **serve_kwargs) -> a running SimBus (stopped after)."""
    stack = []

    def start(ids=(1, 2, 3, 4), **kwargs):
        cm = hw_sim.serve(servos={i: MODEL for i in ids}, **kwargs)
        bus = cm.__enter__()
        stack.append(cm)
        return bus

    yield start
    for cm in reversed(stack):
        cm.__exit__(None, None, None)


@pytest.fixture
def open_reader():
    """Factory: open_reader(bus, ids, **reader_kwargs) -> an opened ServoReader on bus.link."""
    readers = []

    def make(bus, ids=(1, 2, 3, 4), **kwargs):
        kwargs.setdefault("latency_ms", LATENCY_MS)
        reader = ServoReader(bus.link, {i: MODEL for i in ids}, **kwargs)
        reader.open()
        readers.append(reader)
        return reader

    yield make
    for reader in readers:
        reader.close()


def read_until(reader: ServoReader, cond: Callable[[Reading], bool], timeout_s: float = 60.0,
               what: str = "condition", seen: list | None = None) -> Reading:
    """Read until ``cond(reading)`` holds; AssertionError naming ``what`` on timeout (generous:
    a loaded machine is slow, never wrong). ``seen``: a list that gets every reading taken."""
    deadline = time.monotonic() + timeout_s
    while True:
        reading = reader.read()
        if seen is not None:
            seen.append(reading)
        if cond(reading):
            return reading
        if time.monotonic() > deadline:
            raise AssertionError(f"no reading with {what} within {timeout_s} s; last: {reading}; "
                                 f"health: {reader.health}")


def read_n(reader: ServoReader, n: int) -> list[Reading]:
    """``n`` readings in a row (a count, not a duration: a slow machine takes longer)."""
    return [reader.read() for _ in range(n)]


def kinds(reader: ServoReader) -> set[str]:
    return {e.kind for e in reader.log.events}


@pytest.fixture(name="read_until")
def _read_until_fixture():
    return read_until


@pytest.fixture(name="read_n")
def _read_n_fixture():
    return read_n


@pytest.fixture(name="kinds")
def _kinds_fixture():
    return kinds
