"""Shared fixtures: a running simulated bus and the real dynamixel_sdk opened on its pty."""

from __future__ import annotations

import subprocess
import sys
from contextlib import contextmanager

import dynamixel_sdk.port_handler as sdk_port_handler
import pytest

import hw_sim

PATIENT_LATENCY_TIMER = 1000  # ms: a ~2 s deadline rides out kernel stalls (seen past 0.5 s under load)


@pytest.fixture(autouse=True)
def patient_timeouts():
    """Give every SDK call a ~2 s deadline (instead of ~34 ms) so that a loaded 2-core
    machine stalling the bus process cannot fail a read that should succeed."""
    saved = sdk_port_handler.LATENCY_TIMER
    sdk_port_handler.LATENCY_TIMER = PATIENT_LATENCY_TIMER
    yield
    sdk_port_handler.LATENCY_TIMER = saved


@contextmanager
def _short_timeouts():
    saved = sdk_port_handler.LATENCY_TIMER
    sdk_port_handler.LATENCY_TIMER = 1
    try:
        yield
    finally:
        sdk_port_handler.LATENCY_TIMER = saved


@pytest.fixture
def short():
    """``with short():`` makes SDK timeouts cost ~4.5 ms instead of ~34 ms (module global,
    restored after). Use it only around calls expected to time out: on a loaded machine a
    4.5 ms window can miss a reply that does come."""
    saved = sdk_port_handler.LATENCY_TIMER
    yield _short_timeouts
    sdk_port_handler.LATENCY_TIMER = saved


@pytest.fixture
def bus():
    """Three XL330-M288 (ids 1, 2, 3) holding still, timing model off."""
    with hw_sim.serve([1, 2, 3]) as b:
        yield b


@pytest.fixture
def sdk(bus, open_sdk):
    """The SDK opened on ``bus``'s pty (closed after the test, before the bus stops)."""
    return open_sdk(bus.port)


class HwSim:
    """``hw-sim ARGS`` as a user runs it: the port it prints, stopped with Ctrl-C."""

    def __init__(self, interrupt_and_wait, *args: str) -> None:
        self.interrupt_and_wait = interrupt_and_wait
        self.proc = subprocess.Popen([sys.executable, "-m", "hw_sim.cli", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.port = self.proc.stdout.readline().strip()

    def stop(self) -> str:
        """Ctrl-C; its stderr (AssertionError unless it exited 0)."""
        code = self.interrupt_and_wait(self.proc)
        err = self.proc.stderr.read()
        assert code == 0, err
        return err


@pytest.fixture
def hw_sim_command(interrupt_and_wait):
    """Factory: ``hw_sim_command(*args)`` -> a running ``hw-sim ARGS`` (HwSim); the test stops it
    (``stop()``), and any left running is stopped after the test."""
    started = []

    def start(*args: str) -> HwSim:
        sim = HwSim(interrupt_and_wait, *args)
        started.append(sim)
        return sim

    yield start
    for sim in started:
        if sim.proc.poll() is None:
            interrupt_and_wait(sim.proc)
