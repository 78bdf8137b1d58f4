"""``puppet keys --view`` in Debian's Chromium against hw_sim over a pty: Space and the Key
button take a key exactly like Enter (the held pose lands in the shot file; a silent servo
refuses it, named on the page), the onion skins
draw the previous key over the live character (toggling them changes the frame), and dragging
a key's tick on the timeline retimes it in the file (a reorder is refused, the reason on the
page, the file unchanged)."""

from __future__ import annotations

import os
import re
import signal
import subprocess

import numpy as np

import hw_sim
from puppet.rig import builtin
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader
from puppet.view.server import check_input


def pose(rig, degrees: dict[int, float]) -> dict[int, int]:
    """Shaft ticks of every servo for joint angles in degrees (servo id -> angle)."""
    ids = [int(i) for i in rig.servo_map.ids]
    ticks = rig.servo_map.ticks_for(np.radians([degrees.get(i, 0.0) for i in ids]))
    return dict(zip(ids, ticks.tolist()))


def shot_keys(path):
    """The shot's keys as written (None while there is no file)."""
    return TakeReader(path).keys().keys if path.exists() else None


class KeysProcess:
    """``puppet keys ... --view`` with a stdin to type into; ``url`` once it printed it."""

    def __init__(self, tools, args, cwd):
        self.err_path, self.out_path = cwd / "stderr.txt", cwd / "stdout.txt"
        self._err, self._out = open(self.err_path, "w"), open(self.out_path, "w")
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(tools.PUPPET + args, cwd=cwd, stdin=subprocess.PIPE,
                                     stdout=self._out, stderr=self._err, env=env, text=True)

        def url():
            found = re.search(r"view: (http://\S+)", self.err_path.read_text())
            if found:
                return found.group(1)
            assert self.proc.poll() is None, self.err_path.read_text()
            return None
        self.url = tools.wait_until(url, what="the view's URL")

    def type(self, line: str) -> None:
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def stop(self, tools, quit_line: bool = True) -> int:
        """``q`` typed (quit_line) or Ctrl-C, then wait; returns the exit status."""
        if self.proc.poll() is None:
            if quit_line:
                self.type("q")
            else:
                self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(tools.WAIT_S)
            except subprocess.TimeoutExpired:
                self.proc.send_signal(signal.SIGINT)
                self.proc.wait(tools.WAIT_S)
        self._err.close()
        self._out.close()
        return self.proc.returncode


def take_key(tools, page, press, count: int, key_id: int | None = None):
    """Press (Space or the button) until the page says key ``key_id`` (default ``count - 1``,
    the id of a shot's count-th key when none was deleted) was taken: a key refused because a
    read failed on this busy machine is pressed again, as a puppeteer would."""
    key_id = count - 1 if key_id is None else key_id

    def answer():
        seen = page.evaluate("puppetView.keysUpdates")
        press()
        said = tools.wait_js(page, f"puppetView.keysUpdates > {seen} && puppetView.keys.said")
        return said.startswith(f"key {key_id}:")
    tools.wait_until(answer, what=f"key {key_id} taken")


def changed_pixels(a, b) -> int:
    """Pixels whose colour differs by more than JPEG noise between two frames."""
    return int((np.abs(a.astype(int) - b.astype(int)).sum(axis=2) > 60).sum())


def changed_frame(tools, page, other, what: str):
    """The frame shown once it differs from ``other`` by more than JPEG noise in over 300
    pixels (the pose is still: only a change of what the frames show does that)."""
    def changed():
        image = tools.frame_image(page)
        return [image] if changed_pixels(image, other) > 300 else None
    return tools.wait_until(changed, what=what)[0]


def test_keys_from_the_page_onion_skins_and_timeline(new_page, tools, tmp_path):
    rig = builtin()
    ids = [int(i) for i in rig.servo_map.ids]
    shot = tmp_path / "shot.mcap"
    poses = [pose(rig, {4: -60, 5: 40, 1: 20}), pose(rig, {4: 70, 5: -50, 10: -60, 12: 70}),
             pose(rig, {2: -60, 7: -80, 8: -50, 13: -30, 15: 40})]
    with hw_sim.serve(rig.servo_map.models) as bus:
        bus.set_positions(poses[0])
        keys = KeysProcess(tools, ["keys", "--rig", str(BUILTIN_RIG), "--port", bus.port,
                                   "--out", str(shot), "--step", "12",
                                   "--view", str(tools.free_port())], tmp_path)
        try:
            page = tools.open_view(new_page, keys.url)
            tools.wait_js(page, "puppetView.keys !== null")
            assert page.locator("#keys").is_visible()

            # Space takes a key like Enter: the held pose, in the file
            take_key(tools, page, lambda: page.keyboard.press("Space"), 1)
            tools.wait_until(lambda: shot_keys(shot) and len(shot_keys(shot)) == 1, what="key 0 in the file")
            assert shot_keys(shot)[0].frame == 1
            assert shot_keys(shot)[0].ticks.tolist() == [poses[0][i] for i in ids]

            # the Key button too, --step frames later
            bus.set_positions(poses[1])
            take_key(tools, page, lambda: page.click("#key"), 2)
            tools.wait_until(lambda: len(shot_keys(shot)) == 2, what="key 1 in the file")
            assert shot_keys(shot)[1].frame == 13
            assert shot_keys(shot)[1].ticks.tolist() == [poses[1][i] for i in ids]
            assert "key 1: frame 13" in keys.out_path.read_text()  # told on the terminal too

            # a key while a servo is silent is refused on the page, naming it; nothing is taken
            bus.inject("drop", [3])

            def refused_naming_3():
                seen = page.evaluate("puppetView.keysUpdates")
                page.keyboard.press("Space")
                said = tools.wait_js(page, f"puppetView.keysUpdates > {seen} && puppetView.keys.said")
                assert not said.startswith("key 2")
                return "servo(s) [3] flagged" in said
            tools.wait_until(refused_naming_3, what="a refusal naming servo 3 on the page")
            assert page.locator("#keys-said.refused").is_visible()
            assert len(shot_keys(shot)) == 2
            bus.clear_faults()

            # onion skins: the previous key (pose 1) over the live character (pose 2)
            bus.set_positions(poses[2])
            assert page.evaluate("puppetView.keys.onion") is True
            tools.wait_still(page, "puppetView.panel.servos.find(s => s.id === 7) && "
                                   "Math.abs(puppetView.panel.servos.find(s => s.id === 7).deg + 80) < 2")
            with_onion = tools.frame_image(page)
            # toggled off, the ghost of key 1 goes where pose 2 is not; on, it is back
            page.click("#onion")
            tools.wait_js(page, "puppetView.keys.onion === false")
            without = changed_frame(tools, page, with_onion, "the frame without the onion skins")
            page.click("#onion")
            tools.wait_js(page, "puppetView.keys.onion === true")
            again = changed_frame(tools, page, without, "the frame with the onion skins again")
            assert changed_pixels(with_onion, without) > 300
            assert changed_pixels(again, with_onion) < changed_pixels(again, without) / 4
            ghost = (with_onion.astype(int) - without.astype(int))
            assert (ghost[..., 2] > ghost[..., 0] + 40).sum() > 100  # tinted blue: the previous key

            # dragging key 1's tick retimes it in the file
            def drag_tick(start: int, end: int):
                a = page.evaluate(f"puppetView.timelineAt({start})")
                b = page.evaluate(f"puppetView.timelineAt({end})")
                page.mouse.move(a["x"], a["y"])
                page.mouse.down()
                page.mouse.move(b["x"], b["y"], steps=10)
                page.mouse.up()

            drag_tick(13, 20)
            tools.wait_until(lambda: [k.frame for k in shot_keys(shot)] == [1, 20], what="key 1 at frame 20")
            tools.wait_js(page, "puppetView.keys.keys[1].frame === 20")
            assert "key 1: retimed to frame 20" in keys.out_path.read_text()
            # a drag onto key 0's frame is refused, naming both keys, on the page; the file stays
            before = shot.read_bytes()
            drag_tick(20, 1)
            said = tools.wait_js(page, "puppetView.keys.taken === false && puppetView.keys.said")
            assert "key 1 (frame 1) would land on the same frame as key 0 (frame 1)" in said
            assert page.locator("#keys-said.refused").is_visible()
            assert shot.read_bytes() == before
            assert page.evaluate("puppetView.keys.keys.map(k => k.frame)") == [1, 20]
        finally:
            status = keys.stop(tools)
    assert status == 0, keys.err_path.read_text()
    assert "Traceback" not in keys.err_path.read_text()
    assert "keys: 2, 20 frames at 24 fps" in keys.out_path.read_text()


def test_key_edits_from_the_page_go_through_the_terminals_commands(new_page, tools, tmp_path):
    """Select a key by clicking its tick; replace re-poses it, the interpolation menu sets how
    the frames after it are filled, insert adds a key at the red line's frame, delete removes
    the selected key: each rewrites the shot as the terminal's r, m, i and d lines do (the
    terminal tells each outcome too)."""
    rig = builtin()
    ids = [int(i) for i in rig.servo_map.ids]
    shot = tmp_path / "shot.mcap"
    poses = [pose(rig, {4: -60, 5: 40}), pose(rig, {4: 70, 10: -60}), pose(rig, {2: -60, 15: 40})]
    with hw_sim.serve(rig.servo_map.models) as bus:
        bus.set_positions(poses[0])
        keys = KeysProcess(tools, ["keys", "--rig", str(BUILTIN_RIG), "--port", bus.port,
                                   "--out", str(shot), "--step", "12",
                                   "--view", str(tools.free_port())], tmp_path)
        try:
            page = tools.open_view(new_page, keys.url)
            tools.wait_js(page, "puppetView.keys !== null")
            take_key(tools, page, lambda: page.keyboard.press("Space"), 1)
            bus.set_positions(poses[1])
            take_key(tools, page, lambda: page.keyboard.press("Space"), 2)
            tools.wait_until(lambda: shot_keys(shot) and len(shot_keys(shot)) == 2, what="2 keys")
            assert page.locator("#key-replace").is_disabled()  # no key selected yet
            assert page.locator("#key-delete").is_disabled()

            def click_frame(frame: int):
                at = page.evaluate(f"puppetView.timelineAt({frame})")
                page.mouse.click(at["x"], at["y"])

            def edit(press, said: str):
                """Press until the page tells ``said`` (a read failing on this busy machine
                refuses a pose-taking edit: pressed again, as a puppeteer would)."""
                def answer():
                    seen = page.evaluate("puppetView.keysUpdates")
                    press()
                    return tools.wait_js(page, f"puppetView.keysUpdates > {seen} && "
                                               "puppetView.keys.said").startswith(said)
                tools.wait_until(answer, what=said)

            click_frame(1)  # select key 0
            tools.wait_js(page, "puppetView.selectedKey === 0")
            assert page.locator("#key-replace").is_enabled()
            bus.set_positions(poses[2])
            edit(lambda: page.click("#key-replace"), "key 0: replaced")
            tools.wait_until(lambda: shot_keys(shot)[0].ticks.tolist() == [poses[2][i] for i in ids],
                             what="key 0 re-posed in the file")
            assert [k.frame for k in shot_keys(shot)] == [1, 13]

            page.select_option("#key-interpolation", "smooth")  # takes no pose: never refused
            tools.wait_js(page, "puppetView.keys.said === 'key 0: smooth'")
            assert [k.interpolation for k in shot_keys(shot)] == ["smooth", "linear"]

            click_frame(7)  # the red line to frame 7, then insert the held pose there
            tools.wait_js(page, "puppetView.keys.playhead === 7")
            bus.set_positions(poses[0])
            edit(lambda: page.click("#key-insert"), "key 2: inserted at frame 7")  # the next id
            written = shot_keys(shot)
            assert [k.frame for k in written] == [1, 7, 13]
            assert written[1].ticks.tolist() == [poses[0][i] for i in ids]

            click_frame(13)  # select the third tick (key 1: ids are stable) and delete it
            tools.wait_js(page, "puppetView.selectedKey === 2")
            page.click("#key-delete")  # takes no pose: never refused
            tools.wait_js(page, "puppetView.keys.said && puppetView.keys.said.startsWith('key 1: deleted')")
            assert [k.frame for k in shot_keys(shot)] == [1, 7]
            tools.wait_js(page, "puppetView.selectedKey === null")

            keys.type("m 2 step")  # the terminal's line for the same edit
            tools.wait_js(page, "puppetView.keys.said === 'key 2: step'")
            assert [k.interpolation for k in shot_keys(shot)] == ["smooth", "step"]
            # no key selected: the menu sets the interpolation of the keys to come
            page.select_option("#key-interpolation", "smooth")
            tools.wait_js(page, "puppetView.keys.said === 'new keys: smooth'")
            take_key(tools, page, lambda: page.keyboard.press("Space"), 3, key_id=3)  # next id
            tools.wait_until(lambda: len(shot_keys(shot)) == 3, what="key 3 in the file")
            assert [k.interpolation for k in shot_keys(shot)] == ["smooth", "step", "smooth"]
            assert [k.frame for k in shot_keys(shot)] == [1, 7, 19]
            terminal = keys.out_path.read_text()
            for said in ("key 0: replaced", "key 0: smooth", "key 2: inserted at frame 7",
                         "key 1: deleted"):
                assert said in terminal
        finally:
            status = keys.stop(tools)
    assert status == 0, keys.err_path.read_text()
    assert "Traceback" not in keys.err_path.read_text()


def test_live_view_takes_keys_into_a_shot_from_the_page(new_page, tools, tmp_path):
    rig = builtin()
    ids = [int(i) for i in rig.servo_map.ids]
    shot, take = tmp_path / "live-shot.mcap", tmp_path / "live.mcap"
    held = pose(rig, {10: -50, 12: 70, 1: 25})
    with hw_sim.serve(rig.servo_map.models) as bus:
        bus.set_positions(held)
        live = KeysProcess(tools, ["live", "--rig", str(BUILTIN_RIG), "--port", bus.port,
                                   "--record", str(take), "--keys", str(shot),
                                   "--view", str(tools.free_port())], tmp_path)
        try:
            page = tools.open_view(new_page, live.url)
            tools.wait_js(page, "puppetView.keys !== null")
            take_key(tools, page, lambda: page.click("#key"), 1)
            tools.wait_until(lambda: shot_keys(shot) and len(shot_keys(shot)) == 1, what="the key in the file")
            assert shot_keys(shot)[0].ticks.tolist() == [held[i] for i in ids]
            assert shot_keys(shot)[0].frame == 1
        finally:
            status = live.stop(tools, quit_line=False)  # live runs until Ctrl-C
    assert status == 0, live.err_path.read_text()
    assert "Traceback" not in live.err_path.read_text()
    assert f"shot: {shot} (1 keys)" in live.out_path.read_text()
    assert TakeReader(take).metadata is not None  # the take recorded alongside


def test_play_view_of_a_shot_shows_its_keys_at_their_frames(new_page, tools, tmp_path):
    """``play SHOT --view``: the shot plays for (last key frame − 1) / fps seconds and holds its
    end (paused); sought to a key's time, the page's servo angles are that key's."""
    from puppet.take.header import take_header
    from puppet.keys import write_shot
    from puppet.keys.example import critter_keys

    rig = builtin()
    keys = critter_keys(rig, step=12, fps=24)
    shot = tmp_path / "shot.mcap"
    write_shot(shot, take_header(rig), keys)
    play = tools.PuppetProcess(["play", str(shot), "--fps", "24", "--view",
                                str(tools.free_port())], tmp_path)
    try:
        page = tools.open_view(new_page, play)
        tools.wait_js(page, "puppetView.playback !== null && puppetView.playback !== undefined")
        duration = page.evaluate("puppetView.playback.duration_s")
        assert abs(duration - (keys.keys[-1].frame - 1) / 24) < 1e-6
        # at its end the shot holds, paused (a click on pause could land there and play it
        # again: the page's button plays from the start at the end)
        tools.wait_js(page, "puppetView.playback.paused && "
                            "puppetView.playback.position_s === puppetView.playback.duration_s")
        key = keys.keys[2]
        at = (key.frame - 1) / 24
        page.evaluate(f"const s = document.getElementById('scrub'); s.value = '{at}';"
                      "s.dispatchEvent(new Event('input'));")
        tools.wait_js(page, f"Math.abs(puppetView.playback.position_s - {at}) < 0.01")
        want = dict(zip([int(i) for i in rig.servo_map.ids],
                        np.degrees(rig.servo_map.angles(key.ticks)).round(1).tolist()))
        check = " && ".join(f"Math.abs(puppetView.panel.servos.find(s => s.id === {i}).deg - "
                            f"({deg})) < 0.15" for i, deg in want.items())
        tools.wait_js(page, f"puppetView.panel && puppetView.panel.servos && {check}")
    finally:
        status = play.stop()
    assert status == 0, play.stderr()
    assert "Traceback" not in play.stderr()


def test_live_keys_needs_the_view(tools, tmp_path):
    result = tools.cli("live", "--rig", BUILTIN_RIG, "--port", "x", "--keys", tmp_path / "s.mcap")
    assert result.exit_code == 2 and "--keys takes keys from the page: add --view" in result.stderr


def test_key_inputs_from_the_page_are_checked():
    assert check_input({"type": "key"}) is None
    assert check_input({"type": "retime", "index": 1, "frame": 40}) is None
    assert check_input({"type": "retime", "index": 1, "frame": 0}) == "retime: field 'frame' missing or invalid"
    assert check_input({"type": "retime", "index": True, "frame": 4}) == "retime: field 'index' missing or invalid"
    assert check_input({"type": "onion", "on": "yes"}) == "onion: field 'on' missing or invalid"
    assert check_input({"type": "playhead", "frame": 2.5}) == "playhead: field 'frame' missing or invalid"
    edit = {"type": "key_edit", "action": "replace", "index": 0, "frame": 1, "interpolation": "step"}
    assert check_input(edit) is None
    assert check_input({**edit, "action": "new_interpolation"}) is None
    assert check_input({**edit, "action": "goto"}) == "key_edit: field 'action' missing or invalid"
    assert check_input({**edit, "interpolation": "cubic"}) == "key_edit: field 'interpolation' missing or invalid"


def test_keys_view_on_a_taken_port_fails_before_the_bus(tools, tmp_path):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = tools.cli("keys", "--rig", BUILTIN_RIG, "--port", tmp_path / "no-such-port",
                           "--out", tmp_path / "shot.mcap", "--view", port)
    assert result.exit_code == 1
    assert f"Error: --view: address 127.0.0.1:{port} is already in use" in result.stderr
    assert "no-such-port" not in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "shot.mcap").exists()
