"""``role = "actuator"`` in the rig file: an actuator drives a joint the solve fills in; one on a
sensed joint is refused naming the servo, the joint and the line."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from puppet.rig.load import BUILTIN_RIG
from puppet.rig import load_rig
from puppet.rig.errors import RigError

BUILTIN = BUILTIN_RIG.parent
TAIL_RIG = BUILTIN / "critter_tail.toml"


def _tail_rig_text(**replace: str) -> str:
    """critter_tail.toml with its mesh made absolute and ``old=new`` text replacements."""
    text = TAIL_RIG.read_text().replace('mesh = "critter.npz"',
                                        f'mesh = "{(BUILTIN / "critter.npz").as_posix()}"')
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    return text


def _servo_line(text: str, servo_id: int) -> int:
    lines = text.splitlines()
    at = lines.index(f"id = {servo_id}")
    return at  # the [[servo]] header is the line before "id = N" (1-based: at)


def test_tail_rig_actuator_leaves_its_joint_to_the_solve():
    rig = load_rig(TAIL_RIG)
    kinds = rig.bone_kinds()
    assert "tail1" in kinds["free"]
    tail = rig.servo_map.actuators
    assert [(s.id, s.joint, s.role) for s in tail] == [(16, "tail1", "actuator")]
    sensed_dofs = {int(d) for j in rig.skeleton.joints for d in j.dofs}
    assert 15 not in sensed_dofs  # servo 16 is index 15: no joint reads it
    assert len(sensed_dofs) == 15
    # The sensors classify the bones exactly as the plain critter does.
    assert kinds == load_rig(BUILTIN / "critter.toml").bone_kinds()


@pytest.mark.parametrize("joint, why", [("neck", "read by a sensor servo"),
                                        ("hips", "declared fixed")])
def test_actuator_on_a_sensed_joint_is_refused(tmp_path, joint, why):
    text = _tail_rig_text(**{'joint = "tail1"': f'joint = "{joint}"'})
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(RigError) as caught:
        load_rig(path)
    err = caught.value
    assert str(path) in str(err)
    if why == "declared fixed":  # the rig's rule for any servo on a fixed bone says it first
        assert err.line > _servo_line(text, 16) and "fixed" in str(err)
        assert "servo #16" in str(err) or "servo 16" in str(err)
        return
    assert err.line == _servo_line(text, 16)
    assert err.field == "servo 16 role"
    assert f"actuator servo 16 sits on joint {joint!r}" in str(err)
    assert why in str(err)


def test_unknown_role_is_refused(tmp_path):
    text = _tail_rig_text(**{'role = "actuator"': 'role = "motor"'})
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(RigError) as caught:
        load_rig(path)
    assert caught.value.field == "servo 16 role"
    assert caught.value.line == text.splitlines().index('role = "motor"') + 1
    assert "role must be one of sensor, actuator" in str(caught.value)


def test_live_refuses_an_actuator_on_a_sensed_joint(tmp_path):
    text = _tail_rig_text(**{'joint = "tail1"': 'joint = "neck"'})
    path = tmp_path / "bad.toml"
    path.write_text(text)
    done = subprocess.run(["puppet", "live", "--rig", str(path), "--port", "/dev/null",
                           "--seconds", "1"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert f"Error: {path}:{_servo_line(text, 16)}" in done.stderr
    assert "actuator servo 16 sits on joint 'neck'" in done.stderr


def _rig_with_a_model_without_watchdog(tmp_path, monkeypatch):
    """critter_tail.toml whose tail actuator (servo 16) is a model with no Bus Watchdog: every
    model of the table has one, so such a record is made here, as a future model might be."""
    from dataclasses import replace

    from puppet.servo_models import MODELS

    monkeypatch.setitem(MODELS, "XL330-NOWD", replace(MODELS["XL330-M288"], name="XL330-NOWD",
                                                      number=9999, bus_watchdog_firmware=None))
    text = _tail_rig_text(**{'id = 16\nmodel = "XL330-M288"': 'id = 16\nmodel = "XL330-NOWD"'})
    path = tmp_path / "nowd.toml"
    path.write_text(text)
    return load_rig(path), path, text


def test_which_models_of_the_table_have_a_bus_watchdog():
    from puppet.servo_models import MODELS

    # Every X-series and MX(2.0) model has one (firmware 38 on); Protocol 1.0 and the XL-320 none.
    assert {m.name: m.bus_watchdog_firmware for m in MODELS.values() if m.bus_watchdog_firmware != 38} == {
        name: None for name in ("AX-12A", "AX-12W", "AX-18A", "RX-24F", "RX-28", "RX-64", "MX-12W",
                                "MX-28", "MX-64", "MX-106", "XL-320")}


def test_an_actuator_without_bus_watchdog_is_refused_unless_no_watchdog(tmp_path, monkeypatch):
    from puppet.drive.actuators import ActuationPlan

    rig, path, text = _rig_with_a_model_without_watchdog(tmp_path, monkeypatch)
    with pytest.raises(RigError) as caught:
        ActuationPlan.for_rig(rig, 100.0)
    err = caught.value
    assert (err.path, err.line, err.field) == (str(path), _servo_line(text, 16), "servo 16 model")
    assert str(err).startswith(f"{path}:{_servo_line(text, 16)}: servo 16 model: model XL330-NOWD "
                               "has no Bus Watchdog")
    assert "--no-watchdog" in str(err)
    plan = ActuationPlan.for_rig(rig, 100.0, watchdog_ms=0.0)  # live --no-watchdog
    assert (plan.ids, plan.watchdog_units) == ((16,), 0)


def test_perform_refuses_a_model_without_bus_watchdog_unless_no_watchdog(tmp_path, monkeypatch,
                                                                        make_take):
    from puppet.drive import DriveError, PerformOptions, perform
    from puppet.take import TakeReader

    rig, path, text = _rig_with_a_model_without_watchdog(tmp_path, monkeypatch)
    take = make_take(tmp_path / "t.mcap", rig, [[0.0] * len(rig.servo_map.ids)] * 3)
    with pytest.raises(RigError) as caught:
        perform(rig, TakeReader(take), str(tmp_path / "no-port"), PerformOptions(yes=True))
    assert caught.value.field == "servo 16 model"
    assert caught.value.line == _servo_line(text, 16)
    # --no-watchdog: past the rig's check, on to the port (which is not there)
    with pytest.raises(DriveError) as caught:
        perform(rig, TakeReader(take), str(tmp_path / "no-port"),
                PerformOptions(yes=True, watchdog=False))
    assert str(caught.value).startswith(f"performance stopped (torque never went on): port "
                                        f"{tmp_path / 'no-port'}: cannot open")


def test_live_command_refuses_it_naming_servo_model_and_line(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from puppet.cli import main

    _, path, text = _rig_with_a_model_without_watchdog(tmp_path, monkeypatch)
    result = CliRunner().invoke(main, ["live", "--rig", str(path), "--port", "/dev/null",
                                       "--seconds", "1"])
    assert result.exit_code == 1
    assert result.stderr.strip() == (
        f"Error: {path}:{_servo_line(text, 16)}: servo 16 model: model XL330-NOWD has no Bus "
        "Watchdog: if this host stopped, the servo would hold its last goal with torque on; "
        "drive a model that has one, or pass --no-watchdog")
