"""puppet rig axes: a contact sheet with one −30° / +30° pair of panels per servo (and per joint
axis with --all), the positive side framed green, rendered by the offscreen renderer."""

import subprocess

import imageio.v3 as iio
import numpy as np

import pytest

from puppet.render.axes_sheet import (ARROW_PX, BORDER_PX, LABEL_PX, NEGATIVE_TEXT, POSITIVE_BORDER, RING_PX,
                                     WORDS_PX, Turn, turn_transforms, write_words)
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


# ---- each pair from its own camera, along the turn's axis ---------------------------------------
TURNING = {"neck": {"id": 4}, "tail base": {"id": 5, "axis": '"z"'}, "leg.L": {"id": 9, "axis": '"-x"'},
           "foot.L": {"id": 10, "axis": '"y"'}, "tail tip": {"id": 11, "axis": '"x"'}}


@pytest.fixture(scope="module")
def gl_context():
    """One EGL context for this module's sheets, checked for GL errors after them."""
    from puppet.render import create_context

    ctx = create_context()
    yield ctx
    assert ctx.error == "GL_NO_ERROR"
    ctx.release()


def _sheet(tmp_path, character, gl_context, servos=TURNING):
    from puppet.render.axes_sheet import render_turn_sheet
    from puppet.rig.axis_turns import axis_turns

    rig = load_rig(_rig(tmp_path, character, servos))
    sk = rig.skeleton
    turns = [Turn(*t) for t in axis_turns(rig)]
    sheet = render_turn_sheet(rig.V, rig.F, rig.W, sk.heads, sk.tails, sk.parents, turns, angle_deg=30,
                              context=gl_context)
    return rig, turns, sheet


def _panel(sheet, panel):
    top, left, height, width = panel.rect
    return sheet.image[top:top + height, left:left + width]


def test_each_pair_is_seen_along_its_turns_axis(tmp_path, character, gl_context):
    """The axis projects to a point (the ring drawn there), and the turned bone's tip stays at one
    depth: the joint turns in the picture's plane, a sideways swing sideways, a twist in place."""
    rig, turns, sheet = _sheet(tmp_path, character, gl_context)
    sk = rig.skeleton
    assert len(sheet.panels) == 2 * len(turns) == 10
    for k, turn in enumerate(turns):
        minus, plus = sheet.panels[2 * k], sheet.panels[2 * k + 1]
        assert minus.camera is plus.camera
        camera = plus.camera
        _, _, back = camera.basis()
        assert abs(float(back @ turn.axis)) == pytest.approx(1.0, abs=1e-9), turn.label
        right, _, _ = camera.basis()
        length = np.linalg.norm(sk.tails[turn.bone] - sk.heads[turn.bone])
        ends = camera.to_pixels(np.stack([turn.pivot, turn.pivot + length * turn.axis,
                                          turn.pivot + length * right]), PANEL_W, PANEL_H)
        # the axis, as long as the bone, is a dot beside the bone across the picture (perspective
        # leaves a stub: the eye looks along the axis, from the middle of the framed part)
        assert np.linalg.norm(ends[1] - ends[0]) < 0.1 * np.linalg.norm(ends[2] - ends[0]), turn.label
        np.testing.assert_allclose(plus.pivot_px, ends[0], atol=1e-6)
        assert 0 < ends[0][0] < PANEL_W and 0 < ends[0][1] < PANEL_H
        tip = sk.tails[turn.bone]
        depths = []
        for sign in (-1, 1):
            T = turn_transforms(turn, sk.parents, sk.bone_count, sign * np.radians(30)).reshape(-1, 4, 3)
            depths.append(float((tip @ T[turn.bone, :3] + T[turn.bone, 3] - camera.eye) @ back))
        assert depths[0] == pytest.approx(depths[1], abs=1e-9), turn.label
        for panel, ink in ((plus, POSITIVE_BORDER), (minus, NEGATIVE_TEXT)):   # the ring, drawn there
            image = _panel(sheet, panel)
            x, y = (int(round(c)) for c in panel.pivot_px)
            ring = image[y - RING_PX - 1:y + RING_PX + 2, x - RING_PX - 1:x + RING_PX + 2].reshape(-1, 3)
            assert (np.abs(ring.astype(int) - ink).max(axis=1) < 40).sum() >= 2 * RING_PX, panel.label
    # The rendered joint moves: its two panels differ, though both share one camera.
    for k in range(len(turns)):
        minus, plus = (_panel(sheet, p) for p in sheet.panels[2 * k:2 * k + 2])
        inside = (slice(LABEL_PX + 2, PANEL_H - WORDS_PX), slice(BORDER_PX, PANEL_W - BORDER_PX))
        assert (np.abs(plus[inside].astype(int) - minus[inside].astype(int)).max(axis=2) > 30).sum() > 300


def test_each_panel_says_the_turn_in_the_words_of_rig_init(tmp_path, character, gl_context):
    """The words on each panel are rig init's for that joint and axis (``turning +x swings the
    tip down``), the negative panel's those of the opposite turn; they are written in the strip."""
    from puppet.rig.directions import turn_words

    rig, turns, sheet = _sheet(tmp_path, character, gl_context)
    sk = rig.skeleton
    text = (tmp_path / "beast.toml").read_text()
    for k, servo in enumerate(rig.servo_map.servos):
        minus, plus = sheet.panels[2 * k], sheet.panels[2 * k + 1]
        b = sk.index(servo.joint)
        assert plus.words == f"+30°: {turn_words(sk.frames[b], sk.heads[b], sk.tails[b], servo.axis)}"
        assert minus.words == f"-30°: {turn_words(sk.frames[b], sk.heads[b], sk.tails[b], -servo.axis)}"
        # rig init's comment for this joint says the same of a turn about +x, +y or +z
        block = text.split(f"# joint {servo.joint!r}", 1)[1]
        said = block.split("#   turning ", 1)[1].split("\n", 1)[0].split(", ")
        named = next(i for i in range(3) if abs(servo.axis[i]) == 1.0)
        about_plus = said[named].split(" ", 1)[1]   # "swings the tip down" / "twists it"
        panel = plus if servo.axis[named] > 0 else minus
        ours = panel.words.split(": ", 1)[1]
        assert ours.replace("swing its tip", "swings the tip").startswith(about_plus.replace(
            "twists it", "twist it")), (servo.joint, ours, about_plus)
        for p, ink in ((plus, POSITIVE_BORDER), (minus, NEGATIVE_TEXT)):   # written in the strip
            strip = _panel(sheet, p)[PANEL_H - WORDS_PX:PANEL_H - BORDER_PX, BORDER_PX:PANEL_W - BORDER_PX]
            assert (np.abs(strip.astype(int) - ink).max(axis=2) < 60).sum() > 40, p.words


def test_write_words_writes_the_words_in_the_strip():
    panel = np.full((PANEL_H, PANEL_W, 3), 200, np.uint8)
    write_words(panel, "+30°: swing its tip down", (255, 0, 0))
    text = (panel[..., 0] > 150) & (panel[..., 1] < 80)
    assert text[PANEL_H - WORDS_PX:].sum() > 40
    assert text[:PANEL_H - WORDS_PX].sum() == 0 and (panel[:PANEL_H - WORDS_PX] == 200).all()
    other = np.full((PANEL_H, PANEL_W, 3), 200, np.uint8)
    write_words(other, "+30°: twist it about the bone (right-handed about its axis)", (255, 0, 0))
    assert (other[PANEL_H - WORDS_PX:] != panel[PANEL_H - WORDS_PX:]).any()   # the text, not a box


def test_a_small_joint_fills_its_panel(tmp_path, character, gl_context):
    """foot.L is an eighth of the character's size: framed on what it moves, it spans a good
    part of its panel, and its ±30° pictures differ over a good part of the panel."""
    rig, turns, sheet = _sheet(tmp_path, character, gl_context, {"foot.L": {"id": 10, "axis": '"x"'}})
    sk = rig.skeleton
    turn, (minus, plus) = turns[0], sheet.panels
    moving = rig.W[:, sk.index("foot.L")] >= 0.5
    size = np.ptp(rig.V, axis=0).max()
    assert np.ptp(rig.V[moving], axis=0).max() < 0.15 * size   # a small part of the character
    pixels = plus.camera.to_pixels(rig.V[moving], PANEL_W, PANEL_H)
    span = np.ptp(pixels, axis=0)
    assert span[0] > 0.35 * PANEL_W or span[1] > 0.35 * PANEL_H, span
    a, b = _panel(sheet, minus).astype(int), _panel(sheet, plus).astype(int)
    changed = np.abs(a - b).max(axis=2) > 30
    changed[:LABEL_PX + 2] = changed[PANEL_H - WORDS_PX:] = False
    x, y = plus.pivot_px
    rows, cols = np.mgrid[:PANEL_H, :PANEL_W]
    changed[(rows - y) ** 2 + (cols - x) ** 2 < (ARROW_PX + 10) ** 2] = False   # not the arrows
    assert changed.sum() > 0.05 * PANEL_W * PANEL_H, changed.sum()
