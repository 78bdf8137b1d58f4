"""The built-in character: what the issue promises, and that it loads fast with valid weights."""

import json
import subprocess

import numpy as np

from puppet.rig import builtin, load_rig
from puppet.rig.bbw import check_bbw_input
from puppet.servo_models import MODELS


def test_builtin_meets_its_promises():
    rig = builtin()
    assert rig.name == "critter"
    assert 20_000 <= len(rig.F) <= 60_000
    assert rig.V.dtype == np.float64 and rig.F.dtype == np.int32 and rig.W.dtype == np.float64
    assert rig.skeleton.bone_count >= 15
    assert len(rig.servo_map) >= 12
    np.testing.assert_array_equal(rig.servo_map.ids, np.arange(1, len(rig.servo_map) + 1))
    assert set(rig.servo_map.models.values()) <= {"XL330-M288", "XL430-W250", "XM430-W350"}
    assert set(rig.servo_map.models.values()) <= set(MODELS)
    assert np.abs(rig.servo_map.zero - 2048).max() <= 16
    kinds = rig.bone_kinds()
    assert len(kinds["free"]) >= 2 and {"spine", "tail1"} <= set(kinds["free"])
    assert len(kinds["relative"]) >= 1
    # every relative bone has a free bone somewhere above it
    sk = rig.skeleton
    for name in kinds["relative"]:
        chain, i = [], sk.parents[sk.index(name)]
        while i >= 0:
            chain.append(sk.names[i])
            i = sk.parents[i]
        assert set(chain) & set(kinds["free"])
    report = rig.check_weights()
    assert report.ok
    assert report.unused_bones == ()


def test_builtin_mesh_is_closed_and_holds_its_skeleton():
    rig = builtin()
    assert check_bbw_input(rig.V, rig.F, rig.skeleton) == []


def test_builtin_wave_around_2048_gives_sensible_poses():
    rig = builtin()
    values = rig.pattern().values()
    for phase in np.linspace(0, 2 * np.pi, 7):
        ticks = (2048 + 300 * np.sin(phase + np.arange(len(rig.servo_map)))).astype(np.int32)
        angles = rig.servo_map.angles(ticks)
        assert np.abs(angles).max() < np.radians(30)
        rig.fill_values(angles, values)
        assert np.isfinite(values.full).all() and np.isfinite(values.relative).all()
        pose = rig.pose(angles)
        homogeneous = np.concatenate([rig.V, np.ones((len(rig.V), 1))], axis=1)
        moved = np.einsum("nj,jab,nb->na", rig.W, pose, homogeneous)
        displacement = np.linalg.norm(moved - rig.V, axis=1)
        assert 0.005 < displacement.max() < 0.5  # the critter is about 1.3 units tall


def test_rig_info_json_reports_the_builtin():
    result = subprocess.run(["puppet", "rig", "info", "--json"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    assert set(info) >= {"vertices", "triangles", "bones", "servos", "full", "relative", "free",
                         "weights_ok", "load_s"}
    rig = builtin()
    assert info["vertices"] == len(rig.V) and info["triangles"] == len(rig.F)
    assert info["bones"] == rig.skeleton.bone_count and info["servos"] == len(rig.servo_map)
    assert info["full"] == rig.bone_kinds()["full"] and info["free"] == rig.bone_kinds()["free"]
    assert info["weights_ok"] is True
    assert info["load_s"] > 0


def test_rig_info_text_and_bad_rig(tube_rig_dir):
    result = subprocess.run(["puppet", "rig", "info", str(tube_rig_dir / "tube.toml")],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "relative   bone3" in result.stdout and "free       bone2" in result.stdout
    (tube_rig_dir / "tube.toml").write_text('mesh = "tube.obj"\n[[servo]]\nid = 1\n')
    result = subprocess.run(["puppet", "rig", "info", str(tube_rig_dir / "tube.toml")],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert "tube.toml:2: servo 1 model: unknown model None" in result.stderr


def test_the_protocol1_variant_is_the_critter_on_ax12a_and_mx28_as_generated():
    """critter_ax.toml is make_character's text (not a hand copy): the critter's joints, axes,
    signs and limits on one Protocol 1.0 bus, AX-12A on ids 1..8 (zero near 512), MX-28 the rest."""
    import importlib.util
    import tomllib

    from puppet.rig.load import BUILTIN_AX_RIG, BUILTIN_RIG
    from puppet.servo_models import PROTOCOL_1

    # Loaded by path: importing puppet.rig.builtin.make_character would bind the data package
    # over the function puppet.rig.builtin() for every later test in this process.
    spec = importlib.util.spec_from_file_location("make_character",
                                                  BUILTIN_RIG.parent / "make_character.py")
    make_character = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_character)
    AX_IDS, rig_toml = make_character.AX_IDS, make_character.rig_toml

    pin = tomllib.loads(BUILTIN_RIG.read_text())["pin"][0]["vertex"]
    assert BUILTIN_AX_RIG.read_text() == rig_toml(pin, protocol1=True)
    plain, ax = builtin(), load_rig(BUILTIN_AX_RIG)
    models = ax.servo_map.models
    assert {i for i, m in models.items() if m == "AX-12A"} == set(AX_IDS)
    assert set(models.values()) == {"AX-12A", "MX-28"}
    assert {MODELS[m].protocol for m in models.values()} == {PROTOCOL_1}
    assert [(s.joint, s.sign, s.limits) for s in ax.servo_map.servos] == \
        [(s.joint, s.sign, s.limits) for s in plain.servo_map.servos]
    assert all(abs(s.zero_ticks - 512) <= 8 for s in ax.servo_map.servos if s.id in AX_IDS)
    assert ax.V.shape == plain.V.shape
