"""``perform`` and ``release`` on a Protocol 1.0 bus (AX-12A and MX-28 servos) against hw_sim
with the real dynamixel_sdk (``PacketHandler(1.0)``): goal position and moving speed writes at
the models' own addresses, torque off read back on every way out, and the refusal of a model
without a Bus Watchdog unless told."""

from __future__ import annotations

import os
import signal
import subprocess
import threading

import numpy as np
import pytest

import hw_sim
from puppet.drive import DriveError, HealthStop, PerformOptions, perform
from puppet.drive.release import release
from puppet.rig import load_rig
from puppet.rig.errors import RigError
from puppet.take import TakeReader

OPTIONS = dict(yes=True, latency_ms=20, watchdog=False)
AX_IDS = range(1, 9)


@pytest.fixture
def p1_rig(protocol1_rig):
    """The built-in critter on Protocol 1.0 (tests/conftest.py): 1..8 AX-12A, 9..15 MX-28."""
    return load_rig(protocol1_rig)


@pytest.fixture
def p1_take(tmp_path, p1_rig, make_take):
    t = np.arange(100) / 100.0
    k = len(p1_rig.servo_map.ids)
    angles = 15.0 * np.sin(2 * np.pi * 0.5 * t[:, None] + np.arange(k)[None, :])
    return make_take(tmp_path / "wave_p1.mcap", p1_rig, angles)


def _perform(rig, take, port, on_phase=None, **kw):
    return perform(rig, TakeReader(take), port, PerformOptions(**{**OPTIONS, **kw}),
                   on_phase=on_phase)


def _torque(bus, rig):
    return {int(i): bus.servo(int(i)).get("Torque Enable") for i in rig.servo_map.ids}


def _during_playback(action):
    def on_phase(phase):
        if phase == "playback":
            threading.Thread(target=action, daemon=True).start()
    return on_phase


def test_the_p1_rig_loads_with_its_models_ticks_per_turn(p1_rig):
    assert p1_rig.servo_map.units.ticks_per_turn.tolist() == [1228.8] * 8 + [4096.0] * 7


def test_performed_p1_take_tracks_and_ends_with_torque_off(p1_rig, p1_take):
    ids = [int(i) for i in p1_rig.servo_map.ids]
    seen = {}

    def on_phase(phase):
        if phase == "playback":  # what setup and the start wrote, at the P1 addresses
            seen["torque"] = _torque(bus, p1_rig)
            seen["speed"] = {i: bus.servo(i).get("Moving Speed") for i in ids}

    with hw_sim.serve(dict(p1_rig.servo_map.models)) as bus:
        report = _perform(p1_rig, p1_take, bus.port, on_phase=on_phase)
        goals = {i: bus.servo(i).get("Goal Position") for i in ids}
        assert report.stop_reason == "end of take"
        assert report.cycles > 0
        assert 0 <= report.tracking_median_deg <= report.tracking_p99_deg
        # The servos follow the goals, unless the host loop stalled (a starved machine: the
        # report says so, and the servos waited for their next goal meanwhile).
        if not any("goal frames stalled" in line for line in report.log):
            assert report.tracking_p99_deg < 10.0, report.log
        assert report.torque_after == dict.fromkeys(ids, 0)
        assert set(_torque(bus, p1_rig).values()) == {0}
    assert set(seen["torque"].values()) == {1}
    # Moving Speed: the play speed (360 deg/s) in each model's unit, never 0 (= no limit).
    assert seen["speed"] == {i: 541 if i in AX_IDS else 526 for i in ids}
    # The last goals are poses of the take, in each model's own ticks (AX: 0..1023).
    t = np.arange(100) / 100.0
    poses = np.stack([p1_rig.servo_map.ticks_for(np.radians(
        15.0 * np.sin(2 * np.pi * 0.5 * s + np.arange(len(ids))))) for s in t])
    lo, hi = poses.min(axis=0), poses.max(axis=0)
    assert all(lo[k] - 1 <= goals[i] <= hi[k] + 1 for k, i in enumerate(ids))
    assert all(0 <= goals[i] <= 1023 for i in AX_IDS)


def test_a_model_without_bus_watchdog_is_refused_unless_no_watchdog(p1_rig, p1_take):
    with pytest.raises(RigError) as info:
        _perform(p1_rig, p1_take, "/nonexistent/port", watchdog=True)
    assert "servo 1 model: model AX-12A has no Bus Watchdog" in str(info.value)
    assert "--no-watchdog" in str(info.value)


def test_exception_during_playback_leaves_torque_off(p1_rig, p1_take):
    class Boom(RuntimeError):
        pass

    def on_phase(phase):
        if phase == "playback":
            raise Boom("a bug in the loop")

    with hw_sim.serve(dict(p1_rig.servo_map.models)) as bus:
        with pytest.raises(Boom):
            _perform(p1_rig, p1_take, bus.port, on_phase=on_phase)
        assert set(_torque(bus, p1_rig).values()) == {0}


@pytest.mark.parametrize("bad", [3, 12])  # an AX-12A, an MX-28
def test_a_hardware_error_in_the_status_stops_it_naming_the_servo(p1_rig, p1_take, bad):
    with hw_sim.serve(dict(p1_rig.servo_map.models)) as bus:
        with pytest.raises(HealthStop) as info:
            _perform(p1_rig, p1_take, bus.port, loop=True, on_phase=_during_playback(
                lambda: bus.inject("hardware_error", bad, error="overload")))
        assert info.value.dxl_id == bad
        assert str(info.value).startswith(f"servo {bad}:") and "overload" in str(info.value)
        assert set(_torque(bus, p1_rig).values()) == {0}


def test_a_port_lost_and_back_turns_torque_off(p1_rig, p1_take):
    with hw_sim.serve(dict(p1_rig.servo_map.models)) as bus:
        with pytest.raises(DriveError) as info:
            _perform(p1_rig, p1_take, bus.link, loop=True, on_phase=_during_playback(
                lambda: bus.inject("unplug", duration_s=0.5)))
        assert "lost" in str(info.value)
        assert info.value.report.torque_after == dict.fromkeys(map(int, p1_rig.servo_map.ids), 0)
        assert set(_torque(bus, p1_rig).values()) == {0}


def test_release_finds_p1_servos_and_turns_torque_off(p1_rig):
    models = dict(p1_rig.servo_map.models)
    with hw_sim.serve(models) as bus:
        for i in (1, 9):
            bus.servo(i).set("Torque Enable", 1)
        done = release(bus.port)                  # no rig: found by Protocol 1.0 pings
        assert done.torque == dict.fromkeys(models, 0)
        assert done.watchdog == {}                # none of them has a Bus Watchdog
        assert set(_torque(bus, p1_rig).values()) == {0}


def _perform_cli(take, rig_path, port, *extra):
    return subprocess.Popen(["puppet", "perform", str(take), "--rig", str(rig_path), "--port",
                             str(port), "--yes", "--latency-ms", "20", "--no-watchdog", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _wait_playback(proc) -> list[str]:
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if "phase: playback" in line:
            return seen
    raise AssertionError(f"perform exited before playback: {''.join(seen)}")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_stops_a_p1_performance_with_torque_off(p1_rig, p1_take, protocol1_rig, sig):
    with hw_sim.serve(dict(p1_rig.servo_map.models)) as bus:
        proc = _perform_cli(p1_take, protocol1_rig, bus.port, "--loop")
        _wait_playback(proc)
        assert set(_torque(bus, p1_rig).values()) == {1}
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert f"stopped: stopped by {sig.name}" in out
        assert "Traceback" not in err
        assert set(_torque(bus, p1_rig).values()) == {0}


def test_sigkill_without_a_watchdog_leaves_torque_on_until_release(p1_rig, p1_take, protocol1_rig):
    # What --no-watchdog means: nothing on an AX or MX stops it when the host dies, perform and
    # its torque guardian at once (the process group; perform alone: the guardian stops it).
    with hw_sim.serve(dict(p1_rig.servo_map.models)) as bus:
        proc = _perform_cli(p1_take, protocol1_rig, bus.port, "--loop")
        _wait_playback(proc)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate(timeout=120)
        assert set(_torque(bus, p1_rig).values()) == {1}
        result = subprocess.run(["puppet", "release", "--port", bus.port, "--rig",
                                 str(protocol1_rig)], capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr
        assert result.stdout.splitlines()[0] == "servo 1: Torque Enable 0, no Bus Watchdog (read back)"
        assert set(_torque(bus, p1_rig).values()) == {0}


def test_an_ax_in_wheel_mode_is_given_its_range_before_torque(p1_rig, p1_take):
    with hw_sim.serve(dict(p1_rig.servo_map.models)) as bus:
        bus.servo(2).set("CW Angle Limit", 0)
        bus.servo(2).set("CCW Angle Limit", 0)     # both 0: wheel mode, no position control
        report = _perform(p1_rig, p1_take, bus.port)
        assert "servo 2: CCW Angle Limit 0 -> 1023" in report.changes
        assert bus.servo(2).get("CCW Angle Limit") == 1023
        assert report.stop_reason == "end of take"
        assert set(_torque(bus, p1_rig).values()) == {0}
