"""The parts behind the page's keys: the KeyDesk applies commands from any thread in order
(a key waits for its hold window, a ``q`` after it waits too, a retime goes through the shot's
retime rule), the onion skins pick the keys around the playhead, solve each pose once, and blend
their layer over a frame exactly."""

from __future__ import annotations

import threading
import time

import numpy as np

from puppet.take.header import take_header
from puppet.keys.capture import HOLD_NS, KeyDesk, KeySession
from puppet.keys.example import critter_keys
from puppet.reading import Reading
from puppet.rig import builtin
from puppet.take import TakeReader
from puppet.take.keys import Key
from puppet.view.onion import OnionSkins, neighbours


def test_the_desk_applies_presses_from_threads_in_order_after_their_hold_window(tmp_path):
    rig = builtin()
    ids = np.asarray(rig.servo_map.ids)
    shot = tmp_path / "shot.mcap"
    told = []
    desk = KeyDesk(KeySession(shot, take_header(rig), fps=24, step=10),
                   tell=lambda origin, taken, words: told.append((origin, taken, words)))
    held = np.arange(len(ids), dtype=np.int32) + 2000
    press = threading.Thread(target=lambda: (desk.press("", "page"), desk.press("q", "terminal")))
    press.start()
    press.join()
    now = time.monotonic_ns()
    desk.feed([Reading(now + 1_000_000, ids, held, np.ones(len(ids), bool))])
    assert desk.step() == [] and not desk.finished  # the hold window is not over: q waits behind it
    desk.feed([Reading(now + 2 * HOLD_NS, ids, held + 5, np.ones(len(ids), bool))])
    outcomes = desk.step()
    assert [(o, t) for o, t, _ in outcomes] == [("page", True)] and desk.finished
    assert outcomes[0][2].startswith("key 0: frame 1 (1 readings held)")
    assert told == outcomes and desk.version == 1
    assert TakeReader(shot).keys().keys[0].ticks.tolist() == held.tolist()


def test_a_retime_from_the_desk_is_the_shots_retime_rule(tmp_path):
    rig = builtin()
    shot = tmp_path / "shot.mcap"
    session = KeySession(shot, take_header(rig), fps=24, step=12)
    desk = KeyDesk(session)
    session.keys = critter_keys(rig, step=12)  # keys at frames 1, 13, 25, 37
    desk.press("t 2 20", "page")
    desk.press("t 3 13", "page")
    (_, moved, said), (_, refused, why) = desk.step()
    assert moved and said == "key 2: retimed to frame 20"
    assert not refused and "key 3 (frame 13) would land before key 2 (frame 20)" in why
    assert [k.frame for k in TakeReader(shot).keys().keys] == [1, 13, 20, 37]
    assert desk.version == 1


def test_onion_skins_take_the_keys_around_the_playhead():
    keys = [Key(f, np.zeros(2, np.int32), np.ones(2, bool)) for f in (1, 13, 25)]
    assert neighbours(keys, 37) == (keys[2], None)   # after the last key: only the previous
    assert neighbours(keys, 13) == (keys[0], keys[2])  # on a key: the keys either side
    assert neighbours(keys, 14) == (keys[1], keys[2])
    assert neighbours(keys, 1) == (None, keys[1])


def test_each_ghost_is_solved_once_and_the_layer_blends_exactly():
    rig = builtin()
    keys = critter_keys(rig).keys
    onion = OnionSkins(rig, 8, 6)
    try:
        first = onion.ghost_T(keys[1])
        assert onion.ghost_T(keys[1]) is first and onion.solves == 1  # cached by pose
        assert not np.allclose(onion.ghost_T(keys[2]), first) and onion.solves == 2
        onion.forget([keys[2]])
        onion.ghost_T(keys[1])
        assert onion.solves == 3  # forgotten: solved again
    finally:
        onion.close()
    shaded = np.full((6, 8, 3), 100, np.uint8)
    cover = np.zeros((6, 8), np.float32)
    cover[1:5, 2:7] = 1.0  # a 4 x 5 block: its border is the outline, the 2 x 3 inside the body
    drawn = []
    layer = onion.layer(0, "a", [(None, (0.0, 0.0, 255.0))],
                        lambda T: drawn.append(T) or (shaded, cover))
    assert onion.layer(0, "a", [], lambda T: drawn.append(T)) is layer and len(drawn) == 1
    image = np.full((6, 8, 3), 200, np.uint8)
    onion.apply(image, layer)
    colour = 0.4 * 100 + 0.6 * np.array([0.0, 0.0, 255.0])
    body = (1 - 0.45) * 200 + 0.45 * colour
    edge = (1 - 0.9) * 200 + 0.9 * colour
    assert np.abs(image[2, 3].astype(float) - body).max() <= 1
    assert np.abs(image[1, 2].astype(float) - edge).max() <= 1
    assert image[0, 0].tolist() == [200, 200, 200]  # outside the ghost: untouched


def test_the_desk_holds_a_bounded_number_of_waiting_commands(tmp_path):
    from puppet.keys.capture import WAITING_COMMANDS, KeyRefused

    desk = KeyDesk(KeySession(tmp_path / "shot.mcap", take_header(builtin()), fps=24, step=10))
    for _ in range(WAITING_COMMANDS):
        desk.press("")
    try:
        desk.press("", "page")
        refused = None
    except KeyRefused as err:
        refused = str(err)
    assert refused == f"'key' refused: {WAITING_COMMANDS} commands wait already (is the bus reading?)"


def test_interpolation_is_chosen_per_key_while_capturing(tmp_path):
    """``m N KIND`` sets key N's interpolation in the file; ``m KIND`` that of the keys to come;
    an unknown kind is refused naming the kinds, nothing changed."""
    rig = builtin()
    ids = np.asarray(rig.servo_map.ids)
    shot = tmp_path / "shot.mcap"
    session = KeySession(shot, take_header(rig), fps=24, step=12)
    desk = KeyDesk(session)
    session.keys = critter_keys(rig, step=12)  # keys at frames 1, 13, 25, 37, all linear
    for line in ("m 1 smooth", "m 2 wobbly", "m step"):
        desk.press(line, "terminal")
    desk.press("", "terminal")  # a new key after "m step": a step key
    now = time.monotonic_ns()  # after the press: in its hold window
    held, ok = np.full(len(ids), 2048, np.int32), np.ones(len(ids), bool)
    desk.feed([Reading(now + 1_000_000, ids, held, ok), Reading(now + 2 * HOLD_NS, ids, held, ok)])
    outcomes = desk.step()
    assert [t for _, t, _ in outcomes] == [True, False, True, True]
    assert outcomes[0][2] == "key 1: smooth" and outcomes[2][2] == "new keys: step"
    assert "interpolation 'wobbly' is not one of linear, smooth, step" in outcomes[1][2]
    written = TakeReader(shot).keys().keys
    assert [k.interpolation for k in written] == ["linear", "smooth", "linear", "linear", "step"]
    assert [k.frame for k in written] == [1, 13, 25, 37, 49]


def test_ghost_colours_are_their_tints_and_none_is_a_bone_colour():
    """The page's ghost legend names the tints the ghosts are drawn in, and none of them is
    near a colour of the bone legend (a violet ghost is never read as a 'relative' bone)."""
    from puppet.view import onion
    from puppet.view.panel import bone_legend

    def rgb(hex_text):
        return np.array([int(hex_text[i:i + 2], 16) for i in (1, 3, 5)], float)

    tints = {"previous key": onion.PREVIOUS_RGB, "next key": onion.NEXT_RGB,
             "compared take": onion.COMPARE_RGB}
    assert {g["what"]: tuple(rgb(g["color"])) for g in onion.GHOST_LEGEND} == tints
    bones = [rgb(b["color"]) for b in bone_legend()]
    assert len(bones) >= 4
    ghosts = [rgb(g["color"]) for g in onion.GHOST_LEGEND]
    nearest = min(np.linalg.norm(g - b) for g in ghosts for b in bones)
    assert nearest > 80, nearest  # apart in sRGB (0-255 a channel)
    apart = min(np.linalg.norm(a - b) for i, a in enumerate(ghosts) for b in ghosts[i + 1:])
    assert apart > 80, apart
