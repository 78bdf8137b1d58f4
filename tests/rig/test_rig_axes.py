"""puppet rig axes: a contact sheet with one −30° / +30° pair of panels per servo (and per joint
axis with --all), the positive side framed green, rendered by the offscreen renderer."""

import subprocess

import imageio.v3 as iio
import numpy as np

from puppet.render.axes_sheet import BORDER_PX, LABEL_PX, POSITIVE_BORDER, Turn, turn_transforms
from puppet.rig import load_rig

PANEL_W, PANEL_H = 320, 260
SERVOS = {"neck": {"id": 4}, "tail base": {"id": 5, "axis": '"z"'}, "leg.L": {"id": 9, "axis": '"-x"'}}


def run(*args):
    return subprocess.run(["puppet", *map(str, args)], capture_output=True, text=True, timeout=300)


def _rig(tmp_path, character, servos=SERVOS):
    glb = character.write_glb(tmp_path / "beast.glb")
    assert run("rig", "init", glb).returncode == 0
    rig = tmp_path / "beast.toml"
    rig.write_text(character.enable_servos(rig.read_text(), servos))
    return rig


def _pairs(sheet, count, per_row=2):
    """(minus, plus) panels of each of ``count`` turns, laid out ``per_row`` pairs to a row."""
    def panel(r, c):
        return sheet[r * PANEL_H:(r + 1) * PANEL_H, c * PANEL_W:(c + 1) * PANEL_W]

    return [(panel(k // per_row, 2 * (k % per_row)), panel(k // per_row, 2 * (k % per_row) + 1))
            for k in range(count)]


def test_axes_sheet_has_a_pair_of_panels_per_servo(tmp_path, character):
    rig = _rig(tmp_path, character)
    out = tmp_path / "sheet.png"
    result = run("rig", "axes", rig, "--out", out)
    assert result.returncode == 0, result.stderr
    assert "6 panels: 3 pairs" in result.stdout
    sheet = iio.imread(out)
    assert sheet.shape == (2 * PANEL_H, 4 * PANEL_W, 3)  # two pairs to a row
    for minus, plus in _pairs(sheet, 3):
        # The positive panel is framed green, the negative one is not.
        assert (plus[BORDER_PX // 2, PANEL_W // 2] == POSITIVE_BORDER).all()
        assert not (minus[BORDER_PX // 2, PANEL_W // 2] == POSITIVE_BORDER).all()
        # The pictures (below the label strip, inside the border) differ: the joint turned.
        inside = (slice(LABEL_PX + 2, PANEL_H - BORDER_PX), slice(BORDER_PX, PANEL_W - BORDER_PX))
        changed = np.abs(plus[inside].astype(int) - minus[inside].astype(int)).max(axis=2) > 30
        assert changed.sum() > 300


def test_axes_sheet_all_adds_every_joint_without_a_servo(tmp_path, character):
    rig = _rig(tmp_path, character, {"neck": {"id": 4}})
    out = tmp_path / "all.png"
    result = run("rig", "axes", rig, "--out", out, "--all")
    assert result.returncode == 0, result.stderr
    pairs = 1 + 3 * (len(character.NAMES) - 1)
    assert f"{2 * pairs} panels: {pairs} pairs" in result.stdout
    assert iio.imread(out).shape == ((pairs + 1) // 2 * PANEL_H, 4 * PANEL_W, 3)


def test_axes_sheet_of_a_rig_without_servos_shows_every_joint_and_refuses_its_own_input(tmp_path, character):
    rig = _rig(tmp_path, character, {})
    result = run("rig", "axes", rig, "--out", tmp_path / "fresh.png")
    assert result.returncode == 0, result.stderr
    assert "beast.toml: no [[servo]] blocks yet: showing every joint about x, y and z (as --all)" in result.stderr
    pairs = 3 * len(character.NAMES)
    assert f"{2 * pairs} panels: {pairs} pairs" in result.stdout
    assert iio.imread(tmp_path / "fresh.png").shape == ((pairs + 1) // 2 * PANEL_H, 4 * PANEL_W, 3)
    result = run("rig", "axes", rig, "--out", rig, "--all")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert f"{rig}: the axes sheet is also an input of this command" in result.stderr
    result = run("rig", "axes", rig, "--out", tmp_path / "sheet.jpg", "--all")
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "the axes sheet is a PNG" in result.stderr


def test_turn_moves_the_joint_and_its_children_about_the_axis(tmp_path, character):
    """The sheet's pose: +30° about the servo's axis is the rig's own +30° joint angle."""
    rig = load_rig(_rig(tmp_path, character))
    sk = rig.skeleton
    neck = sk.index("neck")
    turn = Turn("neck", neck, sk.frames[neck] @ np.array([1.0, 0, 0]), sk.heads[neck])
    T = turn_transforms(turn, sk.parents, sk.bone_count, np.radians(30)).reshape(-1, 4, 3)
    angles = np.zeros(len(rig.servo_map))
    angles[list(rig.servo_map.ids).index(4)] = np.radians(30)
    pose = rig.pose(angles)  # (bones, 3, 4): forward kinematics of the rig's joint angle
    for bone in (neck, sk.index("head")):
        np.testing.assert_allclose(T[bone, :3].T, pose[bone, :, :3], atol=1e-6)
        np.testing.assert_allclose(T[bone, 3], pose[bone, :, 3], atol=1e-6)
    np.testing.assert_allclose(T[sk.index("spine"), :3], np.eye(3), atol=0)
