"""Rig-file checks that the fuzz suite does not spell out: the rig stays in its room (no native
module, no SDK), one definition of the shared contracts, every model of the one model table is
accepted, and the messages a user needs (free root, unknown model)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import puppet
from puppet.cli import main
from puppet.rig import RigError, Servo, ServoMap, load_rig
from puppet.rig.load import BUILTIN_RIG
from puppet.servo_models import MODELS

PACKAGE = Path(puppet.__file__).parent


def test_reading_a_rig_imports_neither_the_native_solver_nor_the_sdk():
    code = (
        "import sys\n"
        "import puppet.rig\n"
        "rig = puppet.rig.builtin()\n"
        "rig.fill_values(rig.servo_map.angles(rig.servo_map.zero.astype('int32')), rig.pattern().values())\n"
        "puppet.rig.load_rig(puppet.rig.load.BUILTIN_RIG)\n"
        "print(sorted(m for m in ('puppet._native', 'dynamixel_sdk', 'puppet.bus', 'puppet.fast.solver',"
        " 'puppet.fast.model', 'scipy.sparse') if m in sys.modules))\n"
    )
    result = subprocess.run([sys.executable, "-P", "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_the_fast_package_still_offers_its_solver_on_first_use():
    code = ("import sys, puppet.fast as f\n"
            "before = 'puppet._native' in sys.modules\n"
            "print(before, f.FastModel.__name__, f.Solver.__name__, 'puppet._native' in sys.modules)\n")
    result = subprocess.run([sys.executable, "-P", "-c", code], capture_output=True, text=True, timeout=120)
    assert result.stdout.split() == ["False", "FastModel", "Solver", "True"], result.stderr


def test_ticks_per_turn_and_energy_names_are_defined_once():
    definitions = {"ticks": [], "energies": []}
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text()
        if re.search(r"^\s*TICKS_PER_(TURN|REV)\s*=\s*\d", text, re.M):
            definitions["ticks"].append(path.relative_to(PACKAGE).as_posix())
        if re.search(r"^\s*ENERGIES\s*=\s*\(", text, re.M):
            definitions["energies"].append(path.relative_to(PACKAGE).as_posix())
    assert definitions == {"ticks": ["servo_models.py"], "energies": ["fast/energy_names.py"]}
    import puppet.fast.energy as energy
    import puppet.rig

    assert puppet.rig.ENERGIES is energy.ENERGIES


def test_servo_unit_conversions_live_only_in_servo_models():
    # ticks <-> radians or degrees, and per-model units, are coded once (puppet.servo_models):
    # no other module scales by the turn, holds a per-model unit table or its own turn constants.
    copies = re.compile(r"TICKS_PER_TURN\s*/\s*(360|\(?2)|(2\s*\*\s*(np\.|math\.)?pi|360(\.0)?)\s*/\s*"
                        r"TICKS_PER_TURN|4096\s*/\s*360|CURRENT_UNIT_MA|TICKS_PER_DEGREE|"
                        r"^\s*HALF_TURN\s*=|BUS_WATCHDOG_FIRMWARE\s*=", re.M)
    found = sorted(path.relative_to(PACKAGE).as_posix() for path in PACKAGE.rglob("*.py")
                   if path.name != "servo_models.py" and copies.search(path.read_text()))
    assert found == []


def test_every_model_of_the_table_is_accepted_and_others_are_listed(tmp_path):
    text = BUILTIN_RIG.read_text().replace('mesh = "critter.npz"',
                                           f'mesh = "{BUILTIN_RIG.parent / "critter.npz"}"')
    names = [name for name, m in MODELS.items() if m.items.present_position.address == 132][:16]
    for k, name in enumerate(names[:15]):
        text = re.sub(rf'(\[\[servo\]\]\nid = {k + 1}\nmodel = )"[^"]*"', rf'\1"{name}"', text)
    text += f'\n[[servo]]\nid = 16\nmodel = "{names[15]}"\njoint = "spine"\naxis = "x"\n'
    path = tmp_path / "all_models.toml"
    path.write_text(text)
    rig = load_rig(path)
    assert sorted(rig.servo_map.models.values()) == sorted(names)

    bad = tmp_path / "bad_model.toml"
    bad.write_text(text.replace(f'model = "{names[15]}"', 'model = "XC330-M999"'))
    result = CliRunner().invoke(main, ["rig", "info", str(bad)])
    assert result.exit_code == 1
    line = text.splitlines().index(f'model = "{names[15]}"') + 1
    assert f"Error: {bad}:{line}: servo 16 model: unknown model 'XC330-M999' (known: " in result.stderr
    assert all(name in result.stderr for name in names)


def test_a_free_root_without_pins_is_refused_naming_fixed_and_pin(tmp_path):
    text = BUILTIN_RIG.read_text().replace('mesh = "critter.npz"',
                                           f'mesh = "{BUILTIN_RIG.parent / "critter.npz"}"')
    text = text.replace('fixed = ["hips"]\n', "").split("[[pin]]")[0]
    path = tmp_path / "free.toml"
    path.write_text(text)
    with pytest.raises(RigError) as err:
        load_rig(path)
    assert str(err.value).startswith(f"{path}: fixed: nothing holds the character in space")
    assert 'fixed = ["hips"]' in str(err.value) and "[[pin]]" in str(err.value)
    # With a pin instead of the fixed root the rig loads.
    path.write_text(text + "[[pin]]\nvertex = 12279\n")
    assert len(load_rig(path).pins) == 1


def test_a_servo_map_built_in_code_refuses_what_the_file_refuses():
    good = dict(id=1, model="XL330-M288", joint="neck", axis=np.array([1.0, 0, 0]))
    assert len(ServoMap([Servo(**good)])) == 1
    for change, message in [({"axis": np.array([np.nan, 0, 0])}, "servo 1 axis"),
                            ({"gear": float("nan")}, "servo 1 gear"),
                            ({"gear": 1000.0}, "servo 1 gear"),
                            ({"limits": (0.5, -0.5)}, "servo 1 limits"),
                            ({"limits": (-np.inf, 1.0)}, "servo 1 limits"),
                            ({"zero_ticks": 2**40}, "servo 1 zero_ticks"),
                            ({"model": "AX-99Z"}, "servo 1 model")]:
        with pytest.raises(RigError, match=message):
            ServoMap([Servo(**{**good, **change})])


def test_an_empty_glb_is_a_clean_error(tmp_path):
    glb = tmp_path / "empty.glb"
    glb.write_bytes(b"")
    result = CliRunner().invoke(main, ["rig", "info", str(glb)])
    assert result.exit_code == 1
    assert result.stderr.startswith(f"Error: {glb}: 0 bytes: too short for a binary glTF")
