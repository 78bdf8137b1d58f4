"""Shared fixtures for driving servos: the real dynamixel_sdk on a simulated bus."""

from __future__ import annotations

import dynamixel_sdk.port_handler as sdk_port_handler
import numpy as np
import pytest

PATIENT_LATENCY_TIMER = 50  # ms; SDK deadline ~ 2 x this: rides out a loaded machine's stalls


@pytest.fixture(autouse=True)
def patient_timeouts():
    saved = sdk_port_handler.LATENCY_TIMER
    sdk_port_handler.LATENCY_TIMER = PATIENT_LATENCY_TIMER
    yield
    sdk_port_handler.LATENCY_TIMER = saved


@pytest.fixture
def rig():
    """The built-in character's rig (15 servos: XL330, XL430, XM430)."""
    from puppet.rig import builtin

    return builtin()


def _make_take(path, rig, angles_deg, *, rate_hz: float = 100.0, zero=None, ok=None,
               ids=None, models=None, rig_name=None, times_s=None):
    """Write a take of ``angles_deg`` (N, k) joint degrees as recorded by ``rig``'s servos with
    calibration ``zero`` ({id: ticks}; default the rig's). ok: (N, k) bool flags (default all).
    ids/models/rig_name: record it as another rig would. times_s: (N,) reading times (default
    every 1 / rate_hz)."""
    from puppet.reading import Reading
    from puppet.rig.calibration import Calibration
    from puppet.rig.servo_map import ServoMap
    from puppet.take import TakeWriter

    servo_map = ServoMap(rig.servo_map.servos, Calibration(zero) if zero else None)
    if not zero:
        servo_map.zero[:] = rig.servo_map.zero
    angles = np.radians(np.asarray(angles_deg, float))
    n, k = angles.shape
    ok = np.ones((n, k), bool) if ok is None else ok
    take_ids = rig.servo_map.ids if ids is None else np.asarray(ids, np.int64)
    take_models = dict(rig.servo_map.models) if models is None else models
    with TakeWriter(path, ids=take_ids, models=take_models, rig_map_text="",
                    calibration_text=Calibration.capture(servo_map.ids, servo_map.zero).to_record(),
                    rig_name=rig_name or rig.name, overwrite=True) as writer:
        for row in range(n):
            ticks = servo_map.ticks_for(angles[row])[:len(take_ids)]
            t_s = row / rate_hz if times_s is None else times_s[row]
            writer.write(Reading(t_ns=int(t_s * 1e9), ids=take_ids,
                                 ticks=ticks.astype(np.int32), ok=ok[row, :len(take_ids)]))
    return path


@pytest.fixture
def make_take():
    """``make_take(path, rig, angles_deg (N, k), zero=..., ok=..., ids=..., ...)`` -> path."""
    return _make_take


@pytest.fixture
def wave_take(tmp_path, rig):
    """A 0.5 s take at 100 Hz: every joint swings 15 degrees about rest, out of phase (short:
    a performance that ends plays it in real time; tests that stop one mid-way loop it)."""
    t = np.arange(50) / 100.0
    k = len(rig.servo_map.ids)
    angles = 15.0 * np.sin(2 * np.pi * 0.5 * t[:, None] + np.arange(k)[None, :])
    return _make_take(tmp_path / "wave.mcap", rig, angles)


def _read_back(port, models: dict, what: str = "torque_enable", *, latency_ms: int = 20,
               timeout_s: float = 60.0) -> dict[int, int]:
    """{id: ``what``} of ``models``' servos ({id: model}) read over ``port`` through the
    project's own client (BusLink + DriveBus), the port tried again while another process
    still holds it (a command's last process ending)."""
    import time

    from puppet.bus.errors import PortError
    from puppet.bus.link import BusLink
    from puppet.drive.servos import DriveBus
    from puppet.servo_models import protocol_of

    link = BusLink(str(port), baud=1_000_000, latency_ms=latency_ms, protocol=protocol_of(models))
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            link.open()
            break
        except PortError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    try:
        bus = DriveBus(link, list(models), models, lambda _line: None)
        return {int(i): bus.read(i, what) for i in models}
    finally:
        link.close()


@pytest.fixture
def read_back():
    """``read_back(port, {id: model}, what="torque_enable")`` -> {id: value}, read through
    BusLink (see ``_read_back``)."""
    return _read_back
