"""A contact sheet of joint turns: the character with one bone turned −θ and +θ about an axis,
one row per turn, so a builder picks a servo's axis and sign by looking.

Each turn is a pair of panels, −θ then +θ, pairs laid out ``pairs_per_row`` to a row; the
positive panel has a green border and its turned bones are drawn green, the negative one a grey
border and yellow bones. Each pair is seen from its own camera, looking along the turn's axis
(from the side above the ground), so the joint turns in the picture's plane: a sideways swing
looks sideways, a twist spins in place. The camera frames what the turn moves (at −θ, rest and
+θ) and the pivot, so a small joint fills its panel. On each panel: the axis, a ring at the
pivot (a dot: the axis points at the viewer; a cross: away), an arrow the way the panel turns,
and the turn in the words of ``rig init`` ("+30°: swing its tip down"). The character is
skinned by linear blend skinning of the turned bone and its descendants (no solve): what moves
is exactly what the joint moves.

    sheet = render_turn_sheet(V, F, W, heads, tails, parents, turns, angle_deg=30)
    sheet.image      # (ceil(turns / pairs_per_row) * panel_h, 2 * pairs_per_row * panel_w, 3) uint8
    sheet.panels     # one Panel per image panel: label, sign, rect, words, camera, pivot pixel
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from puppet.render.camera import Camera
from puppet.render.errors import RenderInputError

POSITIVE_BORDER = (70, 205, 95)
NEGATIVE_BORDER = (120, 120, 130)
NEGATIVE_TEXT = (220, 220, 225)
STRIP = (24, 24, 28)
BORDER_PX = 5
LABEL_PX = 22
#: The words strip at the bottom of a panel: two lines of text.
WORDS_PX = 44
#: The ring at the pivot and the turn arrow around it, px.
RING_PX, ARROW_PX = 8, 30
#: Degrees of arc the turn arrow sweeps (a direction sign, not the turn's size).
ARROW_SWEEP_DEG = 140.0
#: A turned vertex is framed when this much of its weight moves with the turn.
FOLLOWS = 0.5
#: Framing margin: room for the label and words strips and the arrow.
MARGIN = 1.6
#: A long lens (vertical field of view, degrees): nearly parallel projection, so lines along
#: the axis stay short wherever they are in the panel.
FOV_DEG = 15.0


@dataclass(frozen=True)
class Turn:
    """One pair of panels of the sheet: turn ``bone`` (and its descendants) about ``axis`` at ``pivot``.

    label: text above the panels; bone: bone (handle) index; axis: (3,) unit axis in model
    space; pivot: (3,) point on the axis, model units; words: (positive, negative) what the
    turn does in the character's words (``puppet.rig.directions.turn_words``), or empty.
    """

    label: str
    bone: int
    axis: np.ndarray
    pivot: np.ndarray
    words: tuple[str, str] = ("", "")


@dataclass(frozen=True)
class Panel:
    """One panel of the sheet: its label, sign (+1 / -1), (top, left, height, width) in px, the
    words written on it, the camera it was drawn with and the pivot's pixel (x, y) in it."""

    label: str
    sign: int
    rect: tuple[int, int, int, int]
    words: str = ""
    camera: Camera | None = None
    pivot_px: tuple[float, float] = (0.0, 0.0)


@dataclass
class Sheet:
    image: np.ndarray
    panels: list[Panel]


MAX_PAIRS = 120
"""Pairs of panels one sheet holds (240 renders, a 60-row PNG of about 19 000 x 1 280 px at the
default panel size): a bound, so that a model of a thousand joints with --all is not thousands
of renders and a gigabyte image; ``puppet rig axes`` shows the first ones (servos first) and
says how many it left out."""

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


def turn_camera(turn: Turn, V, W, bones, parents, angle: float, *, aspect: float, up=(0.0, 1.0, 0.0),
                margin: float = MARGIN) -> Camera:
    """The camera of a turn's panels: looking along the turn's axis at what the turn moves.

    V (n, 3), W (n, m): rest character; bones: (b, 2, 3) rest heads and tails; angle: the turn
    shown each way, radians; up: (3,) world up. The frame holds the pivot, the turned bones and
    the vertices that follow the turn (FOLLOWS of their weight) at −angle, rest and +angle. The
    eye is at the end of the axis with fewer still vertices in the way (on a tie: the end above
    the ground), and its near plane cuts away whatever still lies in front of the framed part.
    """
    axis = np.asarray(turn.axis, np.float64) / np.linalg.norm(turn.axis)
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    pivot = np.asarray(turn.pivot, np.float64)
    V = np.asarray(V, np.float64)
    W = np.asarray(W)
    moving = descendants(parents, turn.bone)
    follows = W[:, :len(moving)][:, moving].sum(axis=1) >= FOLLOWS
    carried = np.concatenate([V[follows], bones[moving].reshape(-1, 3)]) - pivot
    points = np.concatenate([pivot[None]] + [carried @ _rotation(axis, a).T + pivot
                                            for a in (-angle, 0.0, angle)])
    rel = points - pivot
    reach = float(np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1).max())
    still = V[~follows] - pivot
    still_along = still @ axis
    still_off = np.linalg.norm(still - np.outer(still_along, axis), axis=1)

    def in_the_way(side: float) -> int:
        front = float((rel @ axis * side).max())
        return int(np.count_nonzero((still_along * side > front) & (still_off < reach)))

    above = 1.0 if axis @ up > -0.5 else -1.0
    view = axis * min((above, -above), key=lambda side: (in_the_way(side), side != above))
    screen_up = up if abs(axis @ up) < 0.9 else np.array([0.0, 0.0, 1.0])  # looking down: forward up
    camera = Camera.framing(points, aspect=aspect, up=screen_up, view=view, margin=margin, fov_deg=FOV_DEG)
    distance = float(np.linalg.norm(camera.eye - camera.target))
    nearest = float(((points - camera.target) @ view).max())  # the framed point nearest the eye
    camera.near = max(distance - nearest - 0.02 * distance, 0.01 * distance)
    return camera


def _font(size: int = 14):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow without FreeType: the small bitmap font
        return ImageFont.load_default()


def _label(panel: np.ndarray, text: str, color) -> None:
    """Draw ``text`` in a dark strip at the top of ``panel`` (h, w, 3) uint8, in place."""
    from PIL import Image, ImageDraw

    image = Image.fromarray(panel)
    draw = ImageDraw.Draw(image)
    draw.rectangle([0, 0, panel.shape[1], LABEL_PX], fill=STRIP)
    draw.text((BORDER_PX + 3, 3), text, fill=color, font=_font())
    panel[:] = np.asarray(image)


def _wrap(draw, text: str, font, width: float, lines: int = 2) -> list[str]:
    """``text`` in at most ``lines`` lines of at most ``width`` px (the last one cut with …)."""
    out, line = [], ""
    for word in text.split():
        trial = f"{line} {word}".strip()
        if line and draw.textlength(trial, font=font) > width:
            out.append(line)
            line = word
        else:
            line = trial
    out.append(line)
    if len(out) > lines:
        out = out[:lines]
        while out[-1] and draw.textlength(out[-1] + "...", font=font) > width:
            out[-1] = out[-1][:-1]
        out[-1] += "..."
    return out


def write_words(panel: np.ndarray, text: str, color) -> None:
    """Write ``text`` (wrapped, two lines at most) in a dark strip at the bottom of ``panel``
    (h, w, 3) uint8, in place: the turn in the character's words."""
    from PIL import Image, ImageDraw

    image = Image.fromarray(panel)
    draw = ImageDraw.Draw(image)
    height, width = panel.shape[:2]
    draw.rectangle([0, height - WORDS_PX, width, height], fill=STRIP)
    font = _font(13)
    for k, line in enumerate(_wrap(draw, text, font, width - 2 * BORDER_PX - 6)):
        draw.text((BORDER_PX + 3, height - WORDS_PX + 3 + 17 * k), line, fill=color, font=font)
    panel[:] = np.asarray(image)


def draw_axis(panel: np.ndarray, camera: Camera, turn: Turn, sign: int, angle_deg: float,
              color) -> tuple[float, float]:
    """Draw the turn's axis on ``panel`` (h, w, 3) uint8, in place: a ring at the pivot with a
    dot (the axis points at the viewer) or a cross (away), a clock hand turned ``angle_deg``
    from a grey rest hand (a twist shows even on a round limb), and an arrow around it the way a
    turn of ``sign`` goes on screen. Returns the pivot's pixel (x, y)."""
    from PIL import Image, ImageDraw

    height, width = panel.shape[:2]
    axis = np.asarray(turn.axis, np.float64) / np.linalg.norm(turn.axis)
    pivot = np.asarray(turn.pivot, np.float64)
    centre = camera.to_pixels(pivot, width, height)[0]
    right, _, back = camera.basis()
    spoke = right - axis * (right @ axis)      # a point off the axis, turned a little by +sign
    spoke *= 0.01 * np.linalg.norm(camera.eye - camera.target) / max(np.linalg.norm(spoke), 1e-12)
    a, b = camera.to_pixels(np.stack([pivot + spoke, pivot + _rotation(axis, sign * 0.2) @ spoke]),
                            width, height) - centre
    clockwise = a[0] * b[1] - a[1] * b[0] > 0  # on screen (y down): the turn's way
    image = Image.fromarray(panel)
    draw = ImageDraw.Draw(image)
    cx, cy = (float(c) for c in centre)
    r = RING_PX
    draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=color, width=2)
    if axis @ back > 0:   # toward the viewer: a dot
        draw.ellipse([cx - 2.5, cy - 2.5, cx + 2.5, cy + 2.5], fill=color)
    else:                 # away: a cross
        d = r * 0.6
        draw.line([cx - d, cy - d, cx + d, cy + d], fill=color, width=2)
        draw.line([cx - d, cy + d, cx + d, cy - d], fill=color, width=2)
    hand = np.array([0.0, -(ARROW_PX - 4)])  # at rest the hand points up the screen
    turn_2d = np.radians(angle_deg) * (1.0 if clockwise else -1.0)
    c, s = np.cos(turn_2d), np.sin(turn_2d)
    turned = np.array([c * hand[0] - s * hand[1], s * hand[0] + c * hand[1]])
    draw.line([cx, cy, cx + hand[0], cy + hand[1]], fill=(150, 150, 160), width=1)
    draw.line([cx, cy, cx + turned[0], cy + turned[1]], fill=color, width=3)
    start = -90.0 - ARROW_SWEEP_DEG / 2 if clockwise else -90.0 + ARROW_SWEEP_DEG / 2
    end = start + ARROW_SWEEP_DEG if clockwise else start - ARROW_SWEEP_DEG
    box = [cx - ARROW_PX, cy - ARROW_PX, cx + ARROW_PX, cy + ARROW_PX]
    draw.arc(box, min(start, end), max(start, end), fill=color, width=3)
    phi = np.radians(end)
    tip = np.array([cx, cy]) + ARROW_PX * np.array([np.cos(phi), np.sin(phi)])
    tangent = np.array([-np.sin(phi), np.cos(phi)]) * (1.0 if clockwise else -1.0)
    normal = np.array([np.cos(phi), np.sin(phi)])
    head = [tip + 5 * tangent, tip - 7 * tangent + 6 * normal, tip - 7 * tangent - 6 * normal]
    draw.polygon([tuple(p) for p in head], fill=color)
    panel[:] = np.asarray(image)
    return cx, cy


def render_turn_sheet(V, F, W, heads, tails, parents, turns: list[Turn], *, angle_deg: float = 30.0,
                      panel_size: tuple[int, int] = (320, 260), pairs_per_row: int = 2,
                      up=(0.0, 1.0, 0.0), context=None,
                      on_pair: Callable[[int], None] | None = None) -> Sheet:
    """Render every turn at −angle and +angle into one sheet, each pair from its own camera
    (``turn_camera``: along the turn's axis, framing what it moves).

    V (n, 3), F (f, 3), W (n, m): the rest character (handles 0..b-1 are the bones);
    heads, tails: (b, 3) rest bones; parents: (b,) parent index or -1; turns: one pair each.
    panel_size: (width, height) px of one panel; pairs_per_row: pairs side by side (fewer when
    there are fewer turns); up: (3,) world up; context: a moderngl context to share;
    on_pair: called with the pairs done after each pair (a progress bar).
    """
    from puppet.render.renderer import Renderer

    if not turns:
        raise RenderInputError("turns: nothing to render (the rig has no servos; use --all for every joint)")
    if len(turns) > MAX_PAIRS:
        raise RenderInputError(f"turns: {len(turns)} pairs; a sheet holds at most {MAX_PAIRS}")
    width, height = (int(x) for x in panel_size)
    W = np.asarray(W)
    parents = np.asarray(parents)
    bones = np.stack([np.asarray(heads, np.float64), np.asarray(tails, np.float64)], axis=1)
    angle = np.radians(angle_deg)
    cameras = [turn_camera(turn, V, W, bones, parents, angle, aspect=width / height, up=up) for turn in turns]
    per_row = max(1, min(int(pairs_per_row), len(turns)))
    rows = -(-len(turns) // per_row)
    image = np.zeros((rows * height, 2 * per_row * width, 3), np.uint8)
    image[:] = STRIP  # an empty slot at the end of the last row
    panels: list[Panel] = []
    with Renderer(V, F, W, width=width, height=height, samples=0, fxaa=True, camera=cameras[0],
                  up=up, ground=False, context=context, bone_width_px=4.0) as renderer:
        for k, (turn, camera) in enumerate(zip(turns, cameras)):
            renderer.camera = camera
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
                ink = border if sign > 0 else NEGATIVE_TEXT
                text = f"{turn.label}  {'+' if sign > 0 else '-'}{angle_deg:g}°"  # the font has no U+2212
                pivot_px = draw_axis(panel, camera, turn, sign, angle_deg, ink)
                _label(panel, text, ink)
                said = turn.words[0 if sign > 0 else 1]
                words = f"{'+' if sign > 0 else '-'}{angle_deg:g}°: {said}" if said else ""
                if words:
                    write_words(panel, words, ink)
                panel[:BORDER_PX], panel[-BORDER_PX:] = border, border
                panel[:, :BORDER_PX], panel[:, -BORDER_PX:] = border, border
                panels.append(Panel(text, sign, (top, left, height, width), words, camera, pivot_px))
            if on_pair is not None:
                on_pair(k + 1)
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
