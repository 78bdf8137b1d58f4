"""The USB serial adapter's latency timer and the SDK's assumption of it.

An FTDI adapter (U2D2, USB2DYNAMIXEL) holds each reply up to its latency timer (Linux default
16 ms); the SDK's read deadlines assume ``dynamixel_sdk.port_handler.LATENCY_TIMER`` ms. Both are
set here: the adapter's timer through sysfs (or the udev rule that sets it), the SDK's assumption
as the process-wide module global it is. No serial IO.
"""

from __future__ import annotations

import os

import dynamixel_sdk.port_handler as sdk_port_handler

DEFAULT_LATENCY_MS = 1
"""The adapter latency the SDK's timeouts assume, ms. FTDI adapters (U2D2) need their
latency_timer set to 1 (udev rule) for this to hold; hw_sim's pty answers at once."""


USB_SERIAL_SYSFS = "/sys/bus/usb-serial/devices"
"""Where Linux keeps each USB serial adapter's settings (``ttyUSBn/latency_timer``)."""
UDEV_RULE = 'ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{latency_timer}="1"'


def _latency_file(port_name: str, root: str) -> str:
    return os.path.join(root, os.path.basename(os.path.realpath(port_name)), "latency_timer")


def adapter_latency_ms(port_name: str, root: str = USB_SERIAL_SYSFS) -> int | None:
    """The FTDI latency timer (ms) of a USB serial adapter (U2D2, USB2DYNAMIXEL), read from
    ``/sys/bus/usb-serial/devices/ttyUSBn/latency_timer``; None for other ports (pty, ACM)."""
    try:
        with open(_latency_file(port_name, root)) as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


def lower_latency_timer(port_name: str, root: str = USB_SERIAL_SYSFS) -> str | None:
    """Set the FTDI latency timer of ``port_name``'s adapter to 1 ms when it is above (the
    Linux default is 16 ms: every reply waits for it, a silent servo costs ~34 ms) -> a line
    saying what was done: the change, or, where the file is not writable (no root), the udev
    rule that sets it; None for a port without the timer or already at 1 ms."""
    before = adapter_latency_ms(port_name, root)
    if before is None or before <= 1:
        return None
    try:
        with open(_latency_file(port_name, root), "w") as f:
            f.write("1")
    except OSError as err:
        return (f"port {port_name}: USB latency timer {before} ms (not writable: {err.strerror}); "
                f"each reply waits up to {before} ms and a silent servo costs about "
                f"{2 * before + 2} ms. Set it to 1 ms: `echo 1 | sudo tee "
                f"{_latency_file(port_name, root)}`, or for good a udev rule: {UDEV_RULE}")
    after = adapter_latency_ms(port_name, root)
    return f"port {port_name}: USB latency timer {before} -> {after} ms"


def set_latency_assumption(ms: int) -> None:
    """Set the SDK's LATENCY_TIMER (ms). A failed read then costs ~2·ms + 2.5 ms.

    It must be set on the submodule ``dynamixel_sdk.port_handler``: the package-level name is a
    copy and has no effect. The value is process-wide (the SDK keeps it as a module global).
    """
    if not 0 < ms <= 255:
        raise ValueError(f"latency assumption {ms} ms: must be in 1..255")
    sdk_port_handler.LATENCY_TIMER = int(ms)


__all__ = ["DEFAULT_LATENCY_MS", "USB_SERIAL_SYSFS", "UDEV_RULE", "adapter_latency_ms",
           "lower_latency_timer", "set_latency_assumption"]
