"""hw_sim drives like a servo: watchdog, time-based profiles, current, overload, temperature,
Moving Status, torque on by goal update (the real dynamixel_sdk over a pty)."""

from __future__ import annotations

import pytest

import hw_sim
from hw_sim.faults import Fault, FaultError
from hw_sim.servo import VELOCITY_UNIT_TICKS_S

DATA_RANGE = 0x04
ACCESS = 0x07


def test_bus_watchdog_trips_refuses_goals_until_cleared(open_sdk, wait_until):
    with hw_sim.serve([1]) as bus:
        sdk = open_sdk(bus.port)
        assert sdk.write(1, 64, 1, 1) == 0
        assert sdk.write(1, 112, 4, 20) == 0        # slow profile
        assert sdk.write(1, 116, 4, 3000) == 0      # start a long move
        assert sdk.write(1, 98, 1, 5) == 0          # 100 ms, then the host falls silent
        servo = bus.servo(1)
        # The host stays silent: the servo stops by itself, holding where it is.
        wait_until(lambda: servo.get("Bus Watchdog") == -1, what="watchdog trip")
        stopped = servo.get("Present Position")
        assert 2048 < stopped < 3000
        assert servo.get("Goal Position") == stopped
        assert servo.get("Torque Enable") == 1
        assert sdk.write(1, 116, 4, 2500) == DATA_RANGE
        assert sdk.write(1, 98, 1, 0) == 0           # cleared
        assert sdk.write(1, 116, 4, 2500) == 0
        assert servo.get("Goal Position") == 2500


def test_bus_watchdog_stays_quiet_while_the_host_talks(open_sdk, wait_until):
    with hw_sim.serve([1]) as bus:
        sdk = open_sdk(bus.port)
        assert sdk.write(1, 64, 1, 1) == 0
        assert sdk.write(1, 98, 1, 100) == 0        # 2 s
        for _ in range(20):
            sdk.read4(1, 132)
        assert bus.servo(1).get("Bus Watchdog") == 100


def test_firmware_without_bus_watchdog_refuses_the_item(open_sdk, wait_until):
    with hw_sim.serve([1]) as bus:
        bus.servo(1).set("Firmware Version", 30)
        sdk = open_sdk(bus.port)
        assert sdk.write(1, 98, 1, 5) == ACCESS


def test_time_based_profile_takes_profile_velocity_ms(open_sdk, wait_until):
    with hw_sim.serve([1]) as bus:
        sdk = open_sdk(bus.port)
        servo = bus.servo(1)
        assert sdk.write(1, 10, 1, 0x04) == 0        # Drive Mode: time-based profile
        assert sdk.write(1, 64, 1, 1) == 0
        assert sdk.write(1, 108, 4, 300) == 0        # 0.3 s ramps
        assert sdk.write(1, 112, 4, 1500) == 0       # 1.5 s move
        assert sdk.write(1, 116, 4, 3048) == 0
        status = servo.get("Moving Status")
        assert status & 0x02 and status & 0x30 == 0x30   # trapezoidal profile ongoing
        # Peak speed of a trapezoid: distance / (total - ramp) = 1000 / 1.2 s.
        peak_units = 1000 / 1.2 / VELOCITY_UNIT_TICKS_S
        speeds = []

        def arrived():
            speeds.append(abs(servo.get("Present Velocity")))
            return servo.get("Moving Status") & 0x01
        wait_until(arrived, what="arrival")
        assert servo.get("Present Position") == 3048
        assert max(speeds) <= peak_units + 1
        assert servo.get("Moving") == 0


def test_torque_on_by_goal_update(open_sdk, wait_until):
    with hw_sim.serve([1]) as bus:
        sdk = open_sdk(bus.port)
        assert sdk.write(1, 10, 1, 0x08) == 0
        assert bus.servo(1).get("Torque Enable") == 0
        assert sdk.write(1, 116, 4, 2100) == 0
        assert bus.servo(1).get("Torque Enable") == 1


def test_current_rises_with_load_and_overload_latches(open_sdk, wait_until):
    with hw_sim.serve([1]) as bus:
        sdk = open_sdk(bus.port)
        servo = bus.servo(1)
        assert sdk.write(1, 64, 1, 1) == 0
        idle = servo.get("Present Current")
        assert idle < 200
        bus.inject("load", 1, current=900)        # the current settles over CURRENT_TAU_S
        wait_until(lambda: servo.get("Present Current") >= 900, what="the load's current")
        bus.inject("load", 1, current=5000)       # beyond the motor: overload, torque off
        wait_until(lambda: servo.get("Hardware Error Status") & 0x20, what="overload")
        assert servo.get("Torque Enable") == 0
        assert sdk.read_status(1, 64) & 0x80


def test_current_rises_with_acceleration(open_sdk, wait_until):
    with hw_sim.serve([1, 2]) as bus:
        sdk = open_sdk(bus.port)
        for i in (1, 2):
            assert sdk.write(i, 64, 1, 1) == 0
            assert sdk.write(i, 112, 4, 300) == 0
        assert sdk.write(1, 108, 4, 10) == 0        # gentle acceleration
        assert sdk.write(2, 108, 4, 2000) == 0      # hard acceleration
        peaks = {1: 0, 2: 0}
        for i in (1, 2):
            assert sdk.write(i, 116, 4, 3500) == 0

        def done():
            for i in (1, 2):
                peaks[i] = max(peaks[i], bus.servo(i).get("Present Current"))
            return all(bus.servo(i).get("Moving Status") & 0x01 for i in (1, 2))
        wait_until(done, what="both arrive", interval=0.001)
        assert peaks[2] > peaks[1]


def test_a_load_may_start_on_an_already_warm_servo(open_sdk, wait_until):
    """The load fault's ``temperature``: the servo is that warm as the load starts and heats on
    from there (0..150 C, else refused naming it)."""
    with hw_sim.serve([1]) as bus:
        sdk = open_sdk(bus.port)
        servo = bus.servo(1)
        assert sdk.write(1, 64, 1, 1) == 0
        assert servo.get("Present Temperature") < 40
        bus.inject("load", 1, current=1500, heat=2, temperature=60)
        # at once (less a moment's cooling while the current builds): ~2 C/s from room
        # temperature would take over ten seconds to get there
        assert servo.get("Present Temperature") >= 55
        wait_until(lambda: servo.get("Present Temperature") >= 61, what="heating on from 60 C")
    with pytest.raises(FaultError, match="temperature=151.0 is not in 0..150"):
        Fault.make("load", 1, temperature=151)


def test_temperature_rises_with_sustained_current(open_sdk, wait_until):
    with hw_sim.serve([1]) as bus:
        sdk = open_sdk(bus.port)
        servo = bus.servo(1)
        assert sdk.write(1, 64, 1, 1) == 0
        start = servo.get("Present Temperature")
        bus.inject("load", 1, current=1500, heat=50)
        wait_until(lambda: servo.get("Present Temperature") >= start + 10, what="heating")
        # Past its own limit the servo latches overheating and lets go.
        wait_until(lambda: servo.get("Hardware Error Status") & 0x04, what="overheating")
        assert servo.get("Torque Enable") == 0


def test_a_rearm_sets_a_goal_within_the_servos_limits_when_its_shaft_is_past_one(wait_until):
    """A shaft past its Min Position Limit when the Bus Watchdog trips: the re-arm's Goal
    Position is the limit, not the present position (which the servo refuses: data range)."""
    from puppet.bus.link import BusLink
    from puppet.drive.servos import DriveBus

    with hw_sim.serve([1]) as bus:
        servo = bus.servo(1)
        present = servo.get("Present Position")
        link = BusLink(str(bus.port), baud=1_000_000, latency_ms=20, protocol=2.0)
        link.open()
        try:
            drive = DriveBus(link, [1], {1: servo.model}, lambda _line: None)
            drive.write(1, "min_position_limit", present + 100)  # the shaft is past it
            drive.prepare(use_watchdog=True)
            assert drive.setup[1].lo == present + 100
            drive.write(1, "torque_enable", 1)
            drive.write(1, "bus_watchdog", 5)  # 100 ms, then the host falls silent
            wait_until(lambda: servo.get("Bus Watchdog") == -1, what="watchdog trip")
            goal = drive.rearm(1, 5)
            assert goal == present + 100 == servo.get("Goal Position")
            assert servo.get("Bus Watchdog") == 5 and servo.get("Torque Enable") == 1
        finally:
            link.close()
