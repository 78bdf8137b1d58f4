"""Shared fixtures for driving servos: the real dynamixel_sdk on a simulated bus."""

from __future__ import annotations

import time

import dynamixel_sdk
import dynamixel_sdk.port_handler as sdk_port_handler
import pytest

BAUD = 1_000_000
PATIENT_LATENCY_TIMER = 50  # ms; SDK deadline ~ 2 x this: rides out a loaded machine's stalls


@pytest.fixture(autouse=True)
def patient_timeouts():
    saved = sdk_port_handler.LATENCY_TIMER
    sdk_port_handler.LATENCY_TIMER = PATIENT_LATENCY_TIMER
    yield
    sdk_port_handler.LATENCY_TIMER = saved


class Sdk:
    """The unmodified SDK on a simulated bus: ``port`` (PortHandler), ``packet`` (Protocol 2.0)."""

    def __init__(self, path: str) -> None:
        self.port = dynamixel_sdk.PortHandler(path)
        assert self.port.openPort() is True
        assert self.port.setBaudRate(BAUD) is True
        self.packet = dynamixel_sdk.PacketHandler(2.0)

    def write(self, dxl_id: int, addr: int, size: int, value: int) -> int:
        """Write and return the status error number (asserting the transaction itself worked)."""
        fn = {1: self.packet.write1ByteTxRx, 2: self.packet.write2ByteTxRx,
              4: self.packet.write4ByteTxRx}[size]
        data = value & ((1 << (8 * size)) - 1)
        code, error = fn(self.port, dxl_id, addr, data)
        assert code == dynamixel_sdk.COMM_SUCCESS
        return error & 0x7F

    def close(self) -> None:
        if self.port.is_open:
            self.port.closePort()


@pytest.fixture
def open_sdk():
    opened = []

    def make(path: str) -> Sdk:
        sdk = Sdk(path)
        opened.append(sdk)
        return sdk

    yield make
    for sdk in opened:
        sdk.close()


def wait_for(condition, timeout_s: float = 60.0, poll_s: float = 0.02, what: str = "condition"):
    """Poll ``condition()`` until it returns a truthy value; that value, or AssertionError."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)
