"""The actuators' cycle hook in the reader process, on hw_sim with the real SDK: the reader's
setup, recovery and auto-reboot leave an actuator's torque alone (the hook decides), and the
hook watches the actuator's Bus Watchdog."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import hw_sim
from puppet.bus.reader_process import ReaderProcess, ReaderProcessError
from puppet.drive.actuators import ActuationPlan, ActuatorHook

MODELS = {1: "XL330-M288", 2: "XL330-M288", 3: "XL330-M288"}
ACTUATOR = 3
WATCHDOG_UNITS = 100  # 2 s: only the tests that want a trip get one


def _plan(watchdog_units: int = WATCHDOG_UNITS) -> ActuationPlan:
    return ActuationPlan((ACTUATOR,), {ACTUATOR: MODELS[ACTUATOR]}, (0.0,), (4095.0,), (20.0,),
                         watchdog_units)


def _source(port, watchdog_units: int = WATCHDOG_UNITS, **options) -> ReaderProcess:
    source = ReaderProcess(port, MODELS, rate_hz=300.0, hook=ActuatorHook(_plan(watchdog_units)),
                           latency_ms=6, **options)
    source.start()
    return source


def _events(source, kind: str, dxl_id: int | None = None) -> list:
    source.drain()
    return [e for e in source.log.events if e.kind == kind and (dxl_id is None or dxl_id in e.ids)]


def _follows(source, bus, goal: int, wait_until, what: str) -> None:
    """The actuator is driven to ``goal`` (its Goal Position reaches it)."""
    def there():
        source.set_goals(np.array([float(goal)]), 0)
        source.drain()
        return bus.servo(ACTUATOR).get("Goal Position") == goal
    wait_until(there, what=what)


def test_the_reader_setup_leaves_the_actuator_to_the_hook(wait_until):
    with hw_sim.serve(MODELS) as bus:
        bus.servo(1).set("Torque Enable", 1)  # a sensor left stiff: the reader turns it off
        source = _source(bus.port)
        try:
            assert bus.servo(1).get("Torque Enable") == 0
            assert bus.servo(ACTUATOR).get("Torque Enable") == 1
            assert bus.servo(ACTUATOR).get("Bus Watchdog") == WATCHDOG_UNITS
            _follows(source, bus, 2100, wait_until, "the actuator's goal written")
        finally:
            source.stop()
        assert source.torque_after == {ACTUATOR: 0}
        assert bus.servo(ACTUATOR).get("Torque Enable") == 0


def test_port_restored_leaves_the_actuator_torque_on(wait_until):
    with hw_sim.serve(MODELS) as bus:
        source = _source(bus.link)
        try:
            _follows(source, bus, 2100, wait_until, "driving before the unplug")
            bus.inject("unplug", duration_s=0.3)
            wait_until(lambda: _events(source, "port_restored"), what="the port restored")
            # The restore reconfigures the group's sensors (on a starved host a sensor's
            # reconfigure can time out: either way the reader has had its go at them).
            wait_until(lambda: _events(source, "reconfigured", 1) or _events(source, "reconfigure_failed", 1),
                       what="sensors reconfigured")
            _follows(source, bus, 2000, wait_until, "driving after the port came back")
            assert bus.servo(ACTUATOR).get("Torque Enable") == 1
            assert all("Torque Enable" not in e.detail
                       for e in _events(source, "reconfigured", ACTUATOR))
        finally:
            source.stop()
        assert source.torque_after == {ACTUATOR: 0}


def test_a_sensor_power_cycle_leaves_the_actuator_torque_on(wait_until):
    with hw_sim.serve(MODELS) as bus:
        source = _source(bus.port)
        try:
            bus.inject("power_cycle", ids=[1], duration_s=0.3)
            wait_until(lambda: _events(source, "reconfigured", 1), what="servo 1 reconfigured")
            _follows(source, bus, 1900, wait_until, "driving after the sensor came back")
            assert bus.servo(ACTUATOR).get("Torque Enable") == 1
        finally:
            source.stop()


def test_an_actuator_that_rebooted_is_stopped_by_the_hook_not_revived(wait_until):
    with hw_sim.serve(MODELS) as bus:
        source = _source(bus.port)
        try:
            bus.inject("power_cycle", ids=[ACTUATOR], duration_s=0.3)
            stopped = wait_until(lambda: _events(source, "actuator_stopped", ACTUATOR),
                                 what="the rebooted actuator stopped")
            assert "rebooted" in stopped[0].detail
            assert bus.servo(ACTUATOR).get("Torque Enable") == 0
            assert source.alive
        finally:
            source.stop()
        assert source.torque_after == {ACTUATOR: 0}


def test_auto_reboot_never_reboots_the_actuator(wait_until):
    with hw_sim.serve(MODELS) as bus:
        source = _source(bus.port, health_period_s=0.05)
        try:
            bus.inject("hardware_error", ids=[1, ACTUATOR], bits=0x04)
            wait_until(lambda: _events(source, "reboot_sent", 1), what="the sensor rebooted")
            stopped = wait_until(lambda: _events(source, "actuator_stopped", ACTUATOR),
                                 what="the actuator stopped by its hook")
            assert "hardware error" in stopped[0].detail
            assert _events(source, "reboot_sent", ACTUATOR) == []
            assert bus.servo(ACTUATOR).hardware_error == 0x04  # still latched: never rebooted
            assert bus.servo(ACTUATOR).get("Torque Enable") == 0
        finally:
            source.stop()


def test_a_tripped_watchdog_is_reported_and_re_armed(wait_until):
    with hw_sim.serve(MODELS) as bus:
        source = _source(bus.port, watchdog_units=5)
        try:
            _follows(source, bus, 2100, wait_until, "driving")
            bus.servo(ACTUATOR).set("Bus Watchdog", -1)  # as a host stall would leave it
            tripped = wait_until(lambda: _events(source, "watchdog_tripped", ACTUATOR),
                                 what="the trip reported")
            assert "re-armed" in tripped[0].detail
            _follows(source, bus, 2300, wait_until, "driving again after the trip")
            assert bus.servo(ACTUATOR).get("Bus Watchdog") == 5
            assert bus.servo(ACTUATOR).get("Torque Enable") == 1
        finally:
            source.stop()
        assert source.log.counts.get("watchdog_tripped", 0) >= 1


def test_a_refused_setup_is_an_error_and_leaves_torque_off():
    with hw_sim.serve(MODELS) as bus:
        bus.servo(ACTUATOR).set("Firmware Version", 30)  # no Bus Watchdog
        source = ReaderProcess(bus.port, MODELS, rate_hz=300.0, hook=ActuatorHook(_plan()))
        with pytest.raises(ReaderProcessError, match="servo 3: firmware 30 has no Bus Watchdog"):
            source.start()
        assert bus.servo(ACTUATOR).get("Torque Enable") == 0


def test_importing_the_bus_imports_nothing_of_drive():
    code = ("import sys, puppet.bus, puppet.bus.reader_process; "
            "print(sorted(m for m in sys.modules if m.startswith('puppet.drive')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_reader_process_killed_has_its_actuators_stopped_from_the_parent(wait_until):
    with hw_sim.serve(MODELS) as bus:
        source = _source(bus.port)
        try:
            assert bus.servo(ACTUATOR).get("Torque Enable") == 1
            source._proc.kill()  # no stop in the child: the hook's stop_from_parent does it
            source._proc.join()
        finally:
            source.stop()
        assert source.torque_after == {ACTUATOR: 0}
        assert bus.servo(ACTUATOR).get("Torque Enable") == 0
        assert bus.servo(ACTUATOR).get("Bus Watchdog") == 0


def test_a_port_gone_for_long_is_noted_with_the_release_command(wait_until):
    with hw_sim.serve(MODELS) as bus:
        source = _source(bus.link)
        try:
            bus.inject("unplug")
            gone = wait_until(lambda: _events(source, "port_gone"), what="the port noted gone")
            assert gone[0].ids == (ACTUATOR,)
            assert f"`puppet release --port {bus.link}` turns it off" in gone[0].detail
        finally:
            source.stop()
        assert source.torque_after == {ACTUATOR: None}  # unreadable: the port is gone
