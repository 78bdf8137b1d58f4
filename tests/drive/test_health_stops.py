"""The current (or load) and temperature stops on every model family, in ``perform`` and in
``live``'s actuator hook, on hw_sim with a ``load`` fault: the host's cap comes from the model
table (no model that senses current goes uncapped), the stop names the servo, and torque ends
off, read back from the simulated servos."""

from __future__ import annotations

import threading
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import hw_sim
from hw_sim.control_table import MODELS as SIM_MODELS
from hw_sim.servo import IDLE_CURRENT_MA
from puppet.bus.reader import ServoReader
from puppet.drive import HealthStop, PerformOptions, perform
from puppet.drive.actuators import WATCHDOG_CHECK_CYCLES, ActuationPlan, ActuatorHook
from puppet.drive.health import CURRENT_FRACTION, TEMPERATURE_CAP_C, TEMPERATURE_MARGIN_C
from puppet.rig.servo_map import ServoMap
from puppet.servo_models import MODELS
from puppet.take import TakeReader

# One model of each family; the load-reporting ones (XL430, XC430) get the same rule on load.
FAMILIES = ["XL330-M288", "XC330-T181", "XC430-W150", "XL430-W250", "XM430-W210", "XH430-W350",
            "XM540-W270"]
OPTIONS = dict(yes=True, latency_ms=20, watchdog_ms=2000.0, loop=True)
LOAD_OF_MOTOR = 0.88
"""The load fault draws this share of the motor's current: above the host cap (0.8 of the
limit) yet, with the idle current, below the motor's own limit, so the servo never trips its
own overload first and the host's stop is the one seen, whatever the machine's load."""
HEAT_C_PER_S = 8.0
"""Heating speed of the temperature cases: the 5-10 C between the host limit and the servo's
own take over half a second, far more than one host cycle."""
WARM_BELOW_LIMIT_C = 3.0
"""The temperature cases' servo is already this far below the host limit as the load starts
(the load fault's ``temperature``): the climb that matters, across the host limit to the
servo's own, is as slow as ever; the minutes up from room temperature are skipped."""


def two_servo_rig(model: str, rig):
    """Servos 1 and 2 of the built-in rig, both of ``model`` (a ServoMap is all perform needs)."""
    servos = [replace(s, model=model) for s in rig.servo_map.servos[:2]]
    return SimpleNamespace(name=f"two {model}", servo_map=ServoMap(servos))


def _during_playback(action):
    def on_phase(phase):
        if phase == "playback":
            threading.Thread(target=action, daemon=True).start()
    return on_phase


def _load_ma(model: str) -> float:
    return LOAD_OF_MOTOR * SIM_MODELS[model].spec.motor_current_ma


def _heat(model: str) -> tuple[float, float]:
    """(current mA, heat gain): a current under the cap heating at HEAT_C_PER_S."""
    current = 0.3 * SIM_MODELS[model].spec.motor_current_ma
    amps = (current + IDLE_CURRENT_MA) / 1000.0
    return current, HEAT_C_PER_S / (0.4 * amps * amps)  # hw_sim.servo.HEATING_C_PER_S_A2


def _host_limit(model: str) -> float:
    return min(MODELS[model].temperature_limit_c - TEMPERATURE_MARGIN_C, TEMPERATURE_CAP_C)


def _expected(model: str, kind: str) -> str:
    m = MODELS[model]
    if kind == "temperature":
        return f"above the host limit {_host_limit(model):.0f} C"
    if m.current_unit_ma is None or m.current_limit is None:
        return "Present Load"  # and the cap, checked in the test
    return f"above the host cap {m.current_limit_ma * CURRENT_FRACTION:.0f} mA"


@pytest.mark.parametrize("model, kind", [(m, "current") for m in FAMILIES] + [
    (m, "temperature") for m in ("XC330-T181", "XL430-W250", "XM540-W270")])  # 70, 72, 80 C
def test_perform_stops_on_current_and_temperature_for_every_family(model, kind, rig, make_take,
                                                                    tmp_path):
    small = two_servo_rig(model, rig)
    take = make_take(tmp_path / "still.mcap", small, np.zeros((20, 2)))
    if kind == "current":
        fault = dict(current=_load_ma(model))
    else:
        current, heat = _heat(model)
        fault = dict(current=current, heat=heat, temperature=_host_limit(model) - WARM_BELOW_LIMIT_C)
    with hw_sim.serve(dict(small.servo_map.models)) as bus:
        with pytest.raises(HealthStop) as info:
            perform(small, TakeReader(take), bus.port, PerformOptions(**OPTIONS),
                    on_phase=_during_playback(lambda: bus.inject("load", 2, **fault)))
        message = str(info.value)
        assert info.value.dxl_id == 2
        assert _expected(model, kind) in message, message
        if kind == "current" and MODELS[model].current_unit_ma is None:
            assert f"above the host cap {100 * CURRENT_FRACTION:.0f} %" in message, message
        assert info.value.report.torque_after == {1: 0, 2: 0}
        assert [bus.servo(i).get("Torque Enable") for i in (1, 2)] == [0, 0]
        assert bus.servo(2).get("Hardware Error Status") == 0  # the host stopped it first


OTHER_FAMILIES = ["AX-12A", "MX-28", "MX-64", "XL-320", "MX-64(2.0)"]
"""Protocol 1.0 (AX, MX: Present Load; no Bus Watchdog), the XL-320 (Present Load, no Bus
Watchdog) and MX(2.0) (Present Current, Current Limit, Bus Watchdog)."""


@pytest.mark.parametrize("model, kind", [(m, "current") for m in OTHER_FAMILIES] + [
    ("AX-12A", "temperature"), ("XL-320", "temperature")])
def test_perform_stops_on_load_and_temperature_for_the_other_families(model, kind, rig, make_take,
                                                                       tmp_path):
    m = MODELS[model]
    servos = [replace(s, model=model, zero_ticks=m.position_ticks // 2)
              for s in rig.servo_map.servos[:2]]
    small = SimpleNamespace(name=f"two {model}", servo_map=ServoMap(servos))
    take = make_take(tmp_path / "still.mcap", small, np.zeros((20, 2)))
    if kind == "current":
        fault = dict(current=_load_ma(model))
    else:
        current, heat = _heat(model)
        fault = dict(current=current, heat=heat, temperature=_host_limit(model) - WARM_BELOW_LIMIT_C)
    options = dict(OPTIONS, watchdog=m.bus_watchdog_firmware is not None)
    with hw_sim.serve(dict(small.servo_map.models)) as bus:
        with pytest.raises(HealthStop) as info:
            perform(small, TakeReader(take), bus.port, PerformOptions(**options),
                    on_phase=_during_playback(lambda: bus.inject("load", 2, **fault)))
        message = str(info.value)
        assert info.value.dxl_id == 2
        assert _expected(model, kind) in message, message
        if kind == "current" and m.current_limit is None:   # the load rule: % of the maximum
            assert f"above the host cap {100 * CURRENT_FRACTION:.0f} %" in message, message
        assert info.value.report.torque_after == {1: 0, 2: 0}
        assert [bus.servo(i).get("Torque Enable") for i in (1, 2)] == [0, 0]
        assert bus.servo(2).hardware_error == 0  # the host stopped it first


@pytest.mark.parametrize("model", FAMILIES)
def test_live_actuator_hook_stops_on_current_for_every_family(model):
    # As the reader process drives a rig's actuators: the hook before each cycle's read.
    servos = {1: model, 2: model}
    plan = ActuationPlan(ids=(2,), models={2: model}, lo=(0.0,), hi=(4095.0,), max_step=(20.0,),
                         watchdog_units=100)
    hook = ActuatorHook(plan)
    with hw_sim.serve(servos) as bus:
        reader = ServoReader(bus.port, servos, driven=hook.ids, latency_ms=20)
        reader.open()
        try:
            hook.start(reader, lambda _text: None)
            assert bus.servo(2).get("Torque Enable") == 1
            bus.inject("load", 2, current=_load_ma(model))
            wanted = np.array([2048.0])
            stopped = []
            deadline = time.monotonic() + 60.0
            while not stopped and time.monotonic() < deadline:
                hook.before_read(reader, wanted)
                reader.read()
                stopped = [e for e in reader.log.drain() if e.kind == "actuator_stopped"]
            assert [e.ids for e in stopped] == [(2,)]
            detail = stopped[0].detail
            assert detail.startswith("Present "), detail
            assert _expected(model, "current") in detail, detail
            assert detail.endswith("stopped, Torque Enable reads 0"), detail
            assert list(hook.active) == [False]
            assert bus.servo(2).get("Torque Enable") == 0
            for _ in range(2 * WATCHDOG_CHECK_CYCLES):  # stopped: nothing more is written
                hook.before_read(reader, wanted)
                reader.read()
            assert bus.servo(2).get("Torque Enable") == 0
        finally:
            hook.stop()
            reader.close()
