"""``perform`` against hw_sim with the real dynamixel_sdk: tracking, the slow start, the stop
paths (torque read back from the simulated servos), the health watchdog, bad input."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest

import hw_sim
from puppet.drive import DriveError, HealthStop, PerformOptions, perform
from puppet.drive.perform import _Health
from puppet.drive.servos import ServoSetup, State
from puppet.servo_models import MODELS
from puppet.take import TakeReader
from puppet.take.errors import TakeRigMismatch

# Patient link (SDK deadline ~40 ms) and watchdog (2 s): a loaded 2-core machine must not
# trip either by itself.
OPTIONS = dict(yes=True, latency_ms=20, watchdog_ms=2000.0)


def _perform(rig, take, port, on_phase=None, **kw):
    return perform(rig, TakeReader(take), port, PerformOptions(**{**OPTIONS, **kw}),
                   on_phase=on_phase)


def _torque(bus, rig):
    return {int(i): bus.servo(int(i)).get("Torque Enable") for i in rig.servo_map.ids}


def _all_off(bus, rig):
    return set(_torque(bus, rig).values()) == {0}


def _during_playback(action):
    """An on_phase callback that runs ``action()`` in a thread once playback begins."""
    def on_phase(phase):
        if phase == "playback":
            threading.Thread(target=action, daemon=True).start()
    return on_phase


def test_performed_take_tracks_and_ends_with_torque_off(rig, wave_take):
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        report = _perform(rig, wave_take, bus.port)
        assert report.stop_reason == "end of take"
        assert report.cycles > 0
        assert 0 <= report.tracking_median_deg <= report.tracking_p99_deg < 10.0
        assert report.torque_after == dict.fromkeys(map(int, rig.servo_map.ids), 0)
        assert _all_off(bus, rig)
        assert {bus.servo(int(i)).get("Bus Watchdog") for i in rig.servo_map.ids} == {0}


def test_start_goes_from_present_no_faster_than_the_start_profile(rig, make_take, tmp_path,
                                                                  wait_until):
    k = len(rig.servo_map.ids)
    take = make_take(tmp_path / "still.mcap", rig, np.full((20, k), 10.0))
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        # The puppet was left away from the take's first pose: torque on must not jump.
        bus.set_positions({int(i): 2048 + 300 * (1 if n % 2 else -1)
                           for n, i in enumerate(rig.servo_map.ids)})
        # Watched from the simulator's side too, from setup until playback begins, once the
        # hand that put them there has let go.
        ids = [int(i) for i in rig.servo_map.ids]
        wait_until(lambda: all(bus.servo(i).get("Present Velocity") == 0 for i in ids),
                   what="the joints at rest")
        seen = dict.fromkeys(ids, 0)
        watching = threading.Event()

        def watch():
            while True:
                for i in ids:
                    speed = abs(bus.servo(i).get("Present Velocity"))
                    if watching.is_set():  # playback began: this reading may be from it
                        return
                    seen[i] = max(seen[i], speed)

        def on_phase(phase):
            if phase == "setup":
                threading.Thread(target=watch, daemon=True).start()
            if phase == "playback":
                watching.set()

        report = _perform(rig, take, bus.port, start_speed_deg_s=40.0, on_phase=on_phase)
        unit = max(MODELS[m].velocity_unit_deg_s for m in rig.servo_map.models.values())
        assert max(seen.values()) > 0
        assert max(seen.values()) * unit <= report.start_profile_deg_s + unit
        assert 40.0 - unit <= report.start_profile_deg_s <= 40.0 + unit
        speeds = report.start_max_speed_deg_s
        assert max(speeds.values()) > 0  # they did move
        assert all(v <= report.start_profile_deg_s + unit for v in speeds.values())
        assert _all_off(bus, rig)


def test_exception_during_playback_leaves_torque_off(rig, wave_take):
    class Boom(RuntimeError):
        pass

    def on_phase(phase):
        if phase == "playback":
            raise Boom("a bug in the loop")

    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(Boom) as info:
            _perform(rig, wave_take, bus.port, on_phase=on_phase)
        assert str(info.value) == "a bug in the loop"
        assert _all_off(bus, rig)


def test_overload_stops_the_performance_naming_the_servo(rig, wave_take):
    # The servo's own overload error (the alert bit of its status) stops it. (A load on an
    # XL430 like servo 4 now meets the host's Present Load cap first: tests/drive/
    # test_health_stops.py; here the servo latches its overload itself.)
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(HealthStop) as info:
            _perform(rig, wave_take, bus.port, loop=True, on_phase=_during_playback(
                lambda: bus.inject("hardware_error", 4, error="overload")))
        assert info.value.dxl_id == 4
        assert "overload" in str(info.value)
        assert str(info.value).startswith("servo 4:")
        assert _all_off(bus, rig)


def test_sustained_current_above_the_host_cap_stops_it(rig, wave_take):
    # Servo 2 is an XL330 (Current Limit 1750 mA): the host cap (80 % for 0.3 s) trips first,
    # unless the host stalls past the servo's own 1 s overload (a loaded machine): then the
    # servo's overload error stops it, also naming it. The cap itself: the test below.
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(HealthStop) as info:
            _perform(rig, wave_take, bus.port, loop=True,
                     on_phase=_during_playback(lambda: bus.inject("load", 2, current=9000)))
        assert info.value.dxl_id == 2
        message = str(info.value)
        assert "Present Current" in message or "hardware error: overload" in message, message
        assert _all_off(bus, rig)


def test_current_above_the_host_cap_stops_once_sustained():
    health = _Health(_two_servos(), PerformOptions(**OPTIONS))
    unit = MODELS["XL330-M288"].current_unit_ma
    over = round(1500 / unit)  # 1500 mA: above the cap, 80 % of the 1750 mA Current Limit
    for _ in range(2):  # 0.2 s over the cap: not sustained yet
        health.check(_state([31, 31], current=[0, over]), dt=0.1)
    health.check(_state([31, 31], current=[0, 0]), dt=0.1)  # back under: the time restarts
    for _ in range(2):
        health.check(_state([31, 31], current=[0, over]), dt=0.1)
    with pytest.raises(HealthStop) as info:  # 0.35 s over the cap
        health.check(_state([31, 31], current=[0, over]), dt=0.15)
    assert info.value.dxl_id == 2
    assert "Present Current" in str(info.value) and "host cap 1400 mA" in str(info.value)


def test_over_temperature_stops_the_performance_naming_the_servo(rig, wave_take):
    # heat 20: about 9 C/s, so the 10 C between the host limit (60) and the servo's own (70)
    # take about a second. A host stalled longer than that (a loaded machine) first reads the
    # servo past its own limit, with its overheating shutdown latched: also a stop naming it.
    # The host limit itself is checked without timing in the test below. The servo is already
    # warm (55 C) as the load starts: the climb from room temperature would only add seconds.
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(HealthStop) as info:
            _perform(rig, wave_take, bus.port, loop=True,
                     on_phase=_during_playback(lambda: bus.inject("load", 3, current=1000, heat=20,
                                                                  temperature=55)))
        assert info.value.dxl_id == 3
        message = str(info.value)
        assert ("Present Temperature" in message and "host limit 60 C" in message
                or "hardware error: overheating" in message), message
        assert _all_off(bus, rig)


def _two_servos():
    """A bus as the health watchdog sees it after setup: XL330s 1 and 2, limits 70 C, 1750 mA."""
    setup = {i: ServoSetup(id=i, model="XL330-M288", firmware=52, temperature_limit=70,
                           current_limit_ma=1750.0, current_unit_ma=1.0) for i in (1, 2)}
    return SimpleNamespace(ids=[1, 2], setup=setup, models={1: "XL330-M288", 2: "XL330-M288"})


def _state(temperatures, current=(0, 0)):
    k = len(temperatures)
    return State(ok=np.ones(k, bool), alert=np.zeros(k, bool), moving=np.zeros(k),
                 moving_status=np.zeros(k), current=np.array(current), velocity=np.zeros(k),
                 position=np.zeros(k), temperature=np.array(temperatures))


def test_temperature_above_the_host_limit_stops_before_the_servos_own():
    health = _Health(_two_servos(), PerformOptions(**OPTIONS))
    health.check(_state([45, 60]), dt=0.01)  # at the limit: goes on
    with pytest.raises(HealthStop) as info:
        health.check(_state([45, 61]), dt=0.01)
    assert info.value.dxl_id == 2
    assert str(info.value) == ("servo 2: Present Temperature 61 C above the host limit 60 C "
                               "(servo limit 70 C); performance stopped, torque off")


def test_vanished_port_stops_by_watchdog_and_next_perform_recovers(rig, wave_take, wait_until):
    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(DriveError) as info:
            _perform(rig, wave_take, bus.link, loop=True,
                     on_phase=_during_playback(lambda: bus.inject("unplug")))
        assert "lost" in str(info.value)
        # Nobody can talk to them: each servo's Bus Watchdog stops it (torque still on).
        wait_until(lambda: all(bus.servo(i).get("Bus Watchdog") == -1 for i in ids),
                   what="every watchdog trips")
        assert set(_torque(bus, rig).values()) == {1}
        assert all(bus.servo(i).get("Present Velocity") == 0 for i in ids)
        bus.clear_faults()  # plugged back in: the same link path works again
        report = _perform(rig, wave_take, bus.link)
        assert sorted(report.recovered) == ids
        assert report.stop_reason == "end of take"
        assert _all_off(bus, rig)


def test_take_from_another_rig_is_refused(rig, make_take, tmp_path):
    k = len(rig.servo_map.ids)
    ids = [int(i) for i in rig.servo_map.ids][:-1]
    models = {i: rig.servo_map.models[i] for i in ids}
    take = make_take(tmp_path / "other.mcap", rig, np.zeros((10, k)), ids=ids, models=models,
                     rig_name="other")
    with pytest.raises(TakeRigMismatch) as info:
        _perform(rig, take, "/nonexistent/port")
    assert "take from another rig" in str(info.value)
    assert "[15]" in str(info.value)


def test_goals_outside_the_limits_are_clamped(rig, make_take, tmp_path):
    k = len(rig.servo_map.ids)
    angles = np.zeros((30, k))
    angles[:, 0] = 60.0  # servo 1 (neck) is limited to +-40 degrees
    take = make_take(tmp_path / "far.mcap", rig, angles)
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        report = _perform(rig, take, bus.port)
        assert report.clamped.get(1, 0) > 0
        assert set(report.clamped) == {1}
        hi = rig.servo_map.ticks_for(np.radians(np.full(k, 40.0)))[0]
        assert abs(bus.servo(1).get("Goal Position") - hi) <= 1


def test_another_calibration_plays_the_same_joint_angles(rig, make_take, tmp_path):
    k = len(rig.servo_map.ids)
    angles = np.full((20, k), 5.0)
    zero = {int(i): int(z) + 100 for i, z in zip(rig.servo_map.ids, rig.servo_map.zero)}
    take = make_take(tmp_path / "other_cal.mcap", rig, angles, zero=zero)
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        _perform(rig, take, bus.port)
        want = rig.servo_map.ticks_for(np.radians(angles[0]))
        got = [bus.servo(int(i)).get("Goal Position") for i in rig.servo_map.ids]
        assert np.abs(np.array(got) - want).max() <= 1


def test_flagged_readings_hold_and_are_reported(rig, make_take, tmp_path):
    k = len(rig.servo_map.ids)
    ok = np.ones((20, k), bool)
    ok[:, 4] = False  # servo 5 never read well: it holds where it is
    take = make_take(tmp_path / "flagged.mcap", rig, np.full((20, k), 20.0), ok=ok)
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        bus.set_positions({5: 2000})
        report = _perform(rig, take, bus.port)
        assert report.flagged == {5: 20}
        assert abs(bus.servo(5).get("Goal Position") - 2000) <= 1


def test_firmware_without_bus_watchdog_is_refused_unless_told(rig, wave_take):
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        bus.servo(7).set("Firmware Version", 30)
        with pytest.raises(DriveError) as info:
            _perform(rig, wave_take, bus.port)
        assert str(info.value).startswith("servo 7: firmware 30 has no Bus Watchdog")
        assert "--no-watchdog" in str(info.value)
        assert _all_off(bus, rig)
        report = _perform(rig, wave_take, bus.port, watchdog=False)
        assert report.stop_reason == "end of take"
        assert _all_off(bus, rig)


def test_wrong_operating_mode_with_torque_on_changes_only_after_torque_off(rig, wave_take):
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        bus.servo(6).set("Operating Mode", 1)
        bus.servo(6).set("Torque Enable", 1)
        report = _perform(rig, wave_take, bus.port)
        mine = [c for c in report.changes if c.startswith("servo 6:")]
        assert mine.index("servo 6: Torque Enable 1 -> 0") < mine.index("servo 6: Operating Mode 1 -> 3")
        assert any("torque is on in operating mode 1" in line for line in report.log)
        assert bus.servo(6).get("Operating Mode") == 3
        assert _all_off(bus, rig)


def test_torque_on_by_goal_update_is_turned_off(rig, wave_take):
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        bus.servo(9).set("Drive Mode", 0x08)
        report = _perform(rig, wave_take, bus.port)
        assert "servo 9: Drive Mode 8 -> 0" in report.changes
        assert _all_off(bus, rig)


def test_countdown_is_announced_and_keeps_the_watchdog_fed(rig, wave_take):
    lines = []
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        report = perform(rig, TakeReader(wave_take), bus.port,
                         PerformOptions(**{**OPTIONS, "yes": False, "countdown_s": 2,
                                           "watchdog_ms": 1000.0}), log=lines.append)
        assert report.stop_reason == "end of take"
        assert any(line.startswith("moving to the first pose") for line in lines)
        assert lines.index("2...") < lines.index("1...")   # 2 s: past the 1 s watchdog
        assert _all_off(bus, rig)


def test_multi_turn_servo_out_of_range_is_refused_before_torque(rig, wave_take, wait_until):
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        bus.servo(1).set("Operating Mode", 4)           # extended position: counts turns
        bus.set_positions({1: 2048 + 2 * 4096})          # turned twice by hand since power-up
        wait_until(lambda: bus.servo(1).get("Present Position") == 2048 + 2 * 4096,
                   what="the turned joint")
        with pytest.raises(DriveError) as info:
            _perform(rig, wave_take, bus.port)
        assert str(info.value).startswith("servo 1: present position 10240 is outside")
        assert "extended position" in str(info.value)
        assert _all_off(bus, rig)


def test_a_silent_servo_is_named_not_the_first_of_the_group(rig, wave_take):
    """A silent servo fails the whole Fast Sync Read; a read of each alone names it."""
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(DriveError) as info:
            _perform(rig, wave_take, bus.port, loop=True,
                     on_phase=_during_playback(lambda: bus.inject("drop", ids=[4])))
        assert str(info.value).startswith("servo 4: no usable reading for 10 cycles, nor alone")
        torque = info.value.report.torque_after
        assert torque[4] is None  # silent: not confirmed
        assert {i: v for i, v in torque.items() if i != 4} == {
            int(i): 0 for i in rig.servo_map.ids if int(i) != 4}


def test_a_short_adapter_drop_ends_with_torque_off(rig, wave_take):
    """The port comes back within the retry window: torque goes off, read back."""
    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(DriveError) as info:
            _perform(rig, wave_take, bus.link, loop=True,
                     on_phase=_during_playback(lambda: bus.inject("unplug", duration_s=0.5)))
        assert str(info.value).startswith("performance stopped (torque off): port ")
        assert "lost" in str(info.value)
        assert info.value.report.torque_after == dict.fromkeys(ids, 0)
        assert _all_off(bus, rig)
        assert {bus.servo(i).get("Bus Watchdog") for i in ids} == {0}


def test_a_port_that_stays_gone_names_the_release_command(rig, wave_take):
    import subprocess

    ids = [int(i) for i in rig.servo_map.ids]
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        with pytest.raises(DriveError) as info:
            _perform(rig, wave_take, bus.link, loop=True,
                     on_phase=_during_playback(lambda: bus.inject("unplug")))
        assert "torque may still be on" in str(info.value)
        assert f"`puppet release --port {bus.link}` turns it off" in str(info.value)
        bus.clear_faults()  # the adapter is back
        result = subprocess.run(["puppet", "release", "--port", str(bus.link), "--rig",
                                 str(rig.path)], capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr
        assert result.stdout.splitlines() == [
            f"servo {i}: Torque Enable 0, Bus Watchdog 0 (read back)" for i in ids]
        assert _all_off(bus, rig)
        assert {bus.servo(i).get("Bus Watchdog") for i in ids} == {0}


def test_damaged_readings_and_cut_gaps_are_said_before_the_port_opens(rig, make_take, tmp_path):
    k = len(rig.servo_map.ids)
    times = np.r_[np.arange(20) / 100.0, 5.0 + np.arange(20) / 100.0]  # a 4.8 s gap: cut
    take = make_take(tmp_path / "damaged.mcap", rig, np.zeros((40, k)), times_s=times)
    data = bytearray(take.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one reading's checksum no longer matches
    take.write_bytes(bytes(data))
    events = []
    with hw_sim.serve(dict(rig.servo_map.models)) as bus:
        report = perform(rig, TakeReader(take), bus.port, PerformOptions(**OPTIONS),
                         log=lambda line: events.append(("log", line)),
                         on_phase=lambda p: events.append(("phase", p)))
        assert _all_off(bus, rig)
    warning = next(i for i, (kind, text) in enumerate(events)
                   if kind == "log" and text.startswith(f"warning: {take}: "))
    assert warning < events.index(("phase", "setup"))  # before anything can turn torque on
    said = events[warning][1]
    assert "skipped 1 damaged record(s) (1 checksum mismatch)" in said
    assert "1 gap(s) between readings longer than 1 s" in said
    assert report.take_damage == said.removeprefix(f"warning: {take}: ")
    assert f"take: {report.take_damage}" in report.text()
    assert report.stop_reason == "end of take"


def test_a_replay_longer_than_the_bound_needs_yes(rig, make_take, tmp_path):
    from puppet.drive.perform import MAX_REPLAY_S

    k = len(rig.servo_map.ids)
    take = make_take(tmp_path / "long.mcap", rig, np.zeros((70, k)), rate_hz=10.0)  # 6.9 s
    assert 6.9 / 0.01 > MAX_REPLAY_S
    options = PerformOptions(**{**OPTIONS, "yes": False}, speed=0.01)
    with pytest.raises(DriveError) as info:  # refused before the (missing) port is opened
        perform(rig, TakeReader(take), "/nonexistent/port", options)
    assert str(info.value) == (f"{take}: the replay would last 690 s at speed 0.01, over 600 s; "
                               "give --yes to perform it")
    assert type(info.value) is DriveError


def test_absurd_options_are_refused_before_the_port_opens(rig, wave_take):
    for name, bad in (("speed", float("nan")), ("speed", 0.0), ("rate_hz", float("inf")),
                      ("watchdog_ms", float("nan")), ("watchdog_ms", 1e9)):
        with pytest.raises(DriveError) as info:  # not a PortError: the port is never opened
            perform(rig, TakeReader(wave_take), "/nonexistent/port",
                    PerformOptions(**{**OPTIONS, name: bad}))
        assert type(info.value) is DriveError
        assert str(info.value).startswith(f"{name} must be a number ")
        assert str(info.value).endswith(f", got {bad!r}")
