"""``puppet release`` on hw_sim with the real SDK: torque off and Bus Watchdog cleared on every
servo found, read back; a port with nothing on it, or a rig servo missing, is an Error line."""

from __future__ import annotations

import subprocess

import hw_sim

MODELS = {1: "XL330-M288", 2: "XL430-W250", 5: "XM430-W350"}


def _release(*args) -> subprocess.CompletedProcess:
    return subprocess.run(["puppet", "release", *map(str, args)], capture_output=True, text=True,
                          timeout=120)


def _stiff(bus, ids) -> None:
    """Servos as a crashed program leaves them: torque on, the watchdog tripped or armed."""
    for dxl_id in ids:
        bus.servo(dxl_id).set("Torque Enable", 1)
        bus.servo(dxl_id).set("Bus Watchdog", -1 if dxl_id == 1 else 5)


def test_release_finds_every_servo_and_turns_torque_off(open_sdk):
    with hw_sim.serve(MODELS) as bus:
        _stiff(bus, MODELS)
        result = _release("--port", bus.port)
        assert result.returncode == 0, result.stderr
        assert result.stdout.splitlines() == [
            f"servo {i}: Torque Enable 0, Bus Watchdog 0 (read back)" for i in MODELS]
        sdk = open_sdk(bus.port)  # an independent client reads them back
        for dxl_id in MODELS:
            assert sdk.read4(dxl_id, 64) & 0xFF == 0   # Torque Enable
            assert sdk.read4(dxl_id, 98) & 0xFF == 0   # Bus Watchdog


def test_release_on_a_port_with_nothing_on_it_says_so():
    with hw_sim.serve(MODELS) as bus:
        bus.inject("power_off")
        port = bus.port
        result = _release("--port", port)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines()[-1] == (
        f"Error: port {port}: no servo of a known model answered a ping at 1000000 bps "
        "(Protocol 2.0 nor 1.0): nothing to release (check the power, the cable and the baud rate)")


def test_release_of_a_rig_names_the_servo_that_did_not_answer(tmp_path):
    from puppet.rig.load import BUILTIN_RIG
    from puppet.rig import load_rig

    rig = load_rig(BUILTIN_RIG)
    models = dict(rig.servo_map.models)
    with hw_sim.serve(models) as bus:
        _stiff(bus, [1, 2])
        bus.inject("power_off", ids=[4])
        port = bus.port
        result = _release("--port", port, "--rig", BUILTIN_RIG)
        assert bus.servo(1).get("Torque Enable") == 0
        assert bus.servo(2).get("Bus Watchdog") == 0
    assert result.returncode == 1
    assert "servo 1: Torque Enable 0, Bus Watchdog 0 (read back)" in result.stdout
    assert "servo 4:" not in result.stdout
    assert result.stderr.strip().splitlines()[-1] == (
        f"Error: port {port}: servo [4] of {BUILTIN_RIG} did not answer: torque unknown")


def test_release_with_another_rig_releases_and_names_the_servos_not_in_it(tmp_path):
    """The rig given names servos 1 and 2; servo 5 on the bus (torque on) is not in it: it is
    released too, and named."""
    from puppet.rig.load import BUILTIN_RIG

    rig_path = _two_servo_rig(tmp_path, BUILTIN_RIG, (1, 2))
    with hw_sim.serve(MODELS) as bus:
        _stiff(bus, MODELS)
        result = _release("--port", bus.port, "--rig", rig_path)
        assert {i: bus.servo(i).get("Torque Enable") for i in MODELS} == dict.fromkeys(MODELS, 0)
        assert bus.servo(5).get("Bus Watchdog") == 0
    assert result.returncode == 0, result.stderr
    assert "servo [5] answered but is not in the rig: released too" in result.stderr
    assert "servo 5: Torque Enable 0, Bus Watchdog 0 (read back)" in result.stdout


def _two_servo_rig(tmp_path, builtin_rig, ids):
    """The built-in rig with only the servo blocks of ``ids`` (its mesh named by full path)."""
    import re

    text = builtin_rig.read_text().replace('mesh = "critter.npz"',
                                           f'mesh = "{builtin_rig.parent / "critter.npz"}"')
    head, *blocks = re.split(r"(?m)^(?=\[\[servo\]\])", text)
    kept = [b for b in blocks if int(re.search(r"(?m)^id\s*=\s*(\d+)", b).group(1)) in ids]
    path = tmp_path / "two.toml"
    path.write_text(head + "".join(kept))
    return path
