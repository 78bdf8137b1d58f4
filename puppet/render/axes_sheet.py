"""A contact sheet of joint turns: the character with one bone turned −θ and +θ about an axis,
one row per turn, so a builder picks a servo's axis and sign by looking.

Each turn is a pair of panels, −θ then +θ, pairs laid out ``pairs_per_row`` to a row; the
positive panel has a green border and its turned bones are drawn green, the negative one a grey
border and yellow bones. The character is skinned
by linear blend skinning of the turned bone and its descendants (no solve): what moves is
exactly what the joint moves.

    sheet = render_turn_sheet(V, F, W, heads, tails, parents, turns, angle_deg=30)
    sheet.image      # (ceil(turns / pairs_per_row) * panel_h, 2 * pairs_per_row * panel_w, 3) uint8
    sheet.panels     # one Panel per image panel: label, sign, (top, left, height, width)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from puppet.render.camera import Camera
from puppet.render.errors import RenderInputError

POSITIVE_BORDER = (70, 205, 95)
NEGATIVE_BORDER = (120, 120, 130)
BORDER_PX = 5
LABEL_PX = 22


@dataclass(frozen=True)
class Turn:
    """One pair of panels of the sheet: turn ``bone`` (and its descendants) about ``axis`` at ``pivot``.

    label: text above the panels; bone: bone (handle) index; axis: (3,) unit axis in model
    space; pivot: (3,) point on the axis, model units.
    """

    label: str
    bone: int
    axis: np.ndarray
    pivot: np.ndarray


@dataclass(frozen=True)
class Panel:
    """One panel of the sheet: its label, sign (+1 / -1) and (top, left, height, width) in px."""

    label: str
    sign: int
    rect: tuple[int, int, int, int]


@dataclass
class Sheet:
    image: np.ndarray
    panels: list[Panel]


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    x, y, z = axis
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def descendants(parents: np.ndarray, bone: int) -> np.ndarray:
    """(b,) bool: ``bone`` and every bone below it."""
    parents = np.asarray(parents)
    moving = np.zeros(len(parents), bool)
    moving[bone] = True
    for i in range(len(parents)):  # parents come before children
        if parents[i] >= 0 and moving[parents[i]]:
            moving[i] = True
    return moving


def turn_transforms(turn: Turn, parents: np.ndarray, handles: int, angle: float) -> np.ndarray:
    """T (4·handles, 3) float32: the turned bone and its descendants rotate by ``angle`` (rad)
    about the turn's axis through its pivot; every other handle stays at rest."""
    R = _rotation(turn.axis, angle)
    t = np.asarray(turn.pivot, np.float64) - R @ np.asarray(turn.pivot, np.float64)
    T = np.zeros((handles, 4, 3), np.float32)
    T[:, :3, :] = np.eye(3)
    moving = np.flatnonzero(descendants(parents, turn.bone))
    T[moving, :3, :] = R.T
    T[moving, 3, :] = t
    return T.reshape(-1, 3)


def _label(panel: np.ndarray, text: str, color) -> None:
    """Draw ``text`` in a dark strip at the top of ``panel`` (h, w, 3) uint8, in place."""
    from PIL import Image, ImageDraw, ImageFont

    image = Image.fromarray(panel)
    draw = ImageDraw.Draw(image)
    draw.rectangle([0, 0, panel.shape[1], LABEL_PX], fill=(24, 24, 28))
    try:
        font = ImageFont.load_default(size=14)
    except (TypeError, OSError):  # Pillow without FreeType: the small bitmap font
        font = ImageFont.load_default()
    draw.text((BORDER_PX + 3, 3), text, fill=color, font=font)
    panel[:] = np.asarray(image)


def render_turn_sheet(V, F, W, heads, tails, parents, turns: list[Turn], *, angle_deg: float = 30.0,
                      panel_size: tuple[int, int] = (320, 260), pairs_per_row: int = 2,
                      camera: Camera | None = None, context=None) -> Sheet:
    """Render every turn at −angle and +angle into one sheet.

    V (n, 3), F (f, 3), W (n, m): the rest character (handles 0..b-1 are the bones);
    heads, tails: (b, 3) rest bones; parents: (b,) parent index or -1; turns: one pair each.
    panel_size: (width, height) px of one panel; pairs_per_row: pairs side by side (fewer when
    there are fewer turns); camera: default frames the rest pose in a
    three-quarter view from the character's front left; context: a moderngl context to share.
    """
    from puppet.render.renderer import Renderer

    if not turns:
        raise RenderInputError("turns: nothing to render (the rig has no servos; use --all for every joint)")
    width, height = (int(x) for x in panel_size)
    W = np.asarray(W)
    parents = np.asarray(parents)
    bones = np.stack([np.asarray(heads, np.float64), np.asarray(tails, np.float64)], axis=1)
    if camera is None:
        camera = Camera.framing(np.concatenate([np.asarray(V, np.float64), bones.reshape(-1, 3)]),
                                aspect=width / height, direction=(1.0, 0.55, 0.75), margin=1.3)
    angle = np.radians(angle_deg)
    per_row = max(1, min(int(pairs_per_row), len(turns)))
    rows = -(-len(turns) // per_row)
    image = np.zeros((rows * height, 2 * per_row * width, 3), np.uint8)
    image[:] = (24, 24, 28)  # an empty slot at the end of the last row
    panels: list[Panel] = []
    with Renderer(V, F, W, width=width, height=height, samples=0, fxaa=True, camera=camera,
                  context=context, bone_width_px=4.0) as renderer:
        for k, turn in enumerate(turns):
            moving = descendants(parents, turn.bone)
            row, pair = divmod(k, per_row)
            for column, sign in enumerate((-1, 1), start=2 * pair):
                T = turn_transforms(turn, parents, W.shape[1], sign * angle)
                states = ["sensed" if (m and sign > 0) else None if m else "free" for m in moving]
                frame = renderer.draw(T, bones=bones, bone_states=states)
                top, left = row * height, column * width
                panel = image[top:top + height, left:left + width]
                panel[:] = frame
                border = POSITIVE_BORDER if sign > 0 else NEGATIVE_BORDER
                text = f"{turn.label}  {'+' if sign > 0 else '-'}{angle_deg:g}°"  # the font has no U+2212
                _label(panel, text, border if sign > 0 else (220, 220, 225))
                panel[:BORDER_PX], panel[-BORDER_PX:] = border, border
                panel[:, :BORDER_PX], panel[:, -BORDER_PX:] = border, border
                panels.append(Panel(text, sign, (top, left, height, width)))
    return Sheet(image, panels)


def save_sheet(sheet: Sheet, path, *, inputs=(), force: bool = False) -> Path:
    """Write the sheet as a PNG, atomically, by ``puppet.atomic``'s rule (not one of
    ``inputs``; an existing file of another kind only with ``force``)."""
    import imageio.v3 as iio

    from puppet.atomic import atomic_output

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise RenderInputError(f"{path}: the axes sheet is a PNG; name it ....png")
    with atomic_output(path, kind="png", inputs=inputs, force=force, what="axes sheet") as temporary:
        iio.imwrite(temporary, sheet.image)
    return path
