"""The view's commands: a taken port fails before any hardware, ``puppet view`` beyond loopback
refuses pages without the token and poses the rig by drags, ``puppet play TAKE --view`` pauses
and seeks."""

from __future__ import annotations

import math
import socket
import subprocess
import urllib.error
import urllib.request

import aiohttp
import numpy as np
import pytest

from puppet.rig import builtin
from puppet.view.frames import KEEPALIVE_S


def run_puppet(tools, *args, timeout=300):
    return subprocess.run(tools.PUPPET + list(args), capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def taken_port():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        yield taken.getsockname()[1]


def test_a_taken_port_fails_before_the_bus_is_touched(tools, taken_port, tmp_path):
    message = f"Error: --view: address 127.0.0.1:{taken_port} is already in use (port {taken_port})"
    demo = run_puppet(tools, "demo", "--view", str(taken_port), "--seconds", "1",
                      "--out", str(tmp_path / "demo.mp4"))
    assert demo.returncode == 1
    assert message in demo.stderr
    assert "Traceback" not in demo.stderr
    assert not (tmp_path / "demo.mp4").exists()  # the loop never ran
    # live names the view's address, not the (absent) serial port: the view was bound first
    # (in this process: the command line's way from an error to its exit is the one above).
    live = tools.cli("live", "--rig", builtin().path, "--port", tmp_path / "no-such-port",
                     "--view", f"127.0.0.1:{taken_port}")
    assert live.exit_code == 1
    assert message in live.stderr
    assert "no-such-port" not in live.stderr


async def _socket_status(url: str, origin: str) -> int:
    async with aiohttp.ClientSession() as session:
        try:
            async with session.ws_connect(url, origin=origin):
                return 101
        except aiohttp.WSServerHandshakeError as err:
            return err.status


def test_view_beyond_loopback_needs_the_token_and_poses_by_drags(new_page, tools, tmp_path):
    port = tools.free_port()
    view = tools.PuppetProcess(["view", "--address", f"0.0.0.0:{port}"], tmp_path)
    try:
        assert "?token=" in view.url
        token = view.url.split("?token=")[1]
        local = f"http://127.0.0.1:{port}/"
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(local, timeout=30)
        assert refused.value.code == 403
        with pytest.raises(urllib.error.HTTPError) as wrong:
            urllib.request.urlopen(local + "?token=" + token[:-2] + "xx", timeout=30)
        assert wrong.value.code == 403
        with pytest.raises(urllib.error.HTTPError) as script:
            urllib.request.urlopen(local + "static/view.js", timeout=30)
        assert script.value.code == 403
        origin = f"http://127.0.0.1:{port}"
        ws = f"ws://127.0.0.1:{port}/ws/control?client=abc"
        assert tools.run_async(_socket_status(ws, origin)) == 403
        assert tools.run_async(_socket_status(f"{ws}&token={token}", "http://evil.example")) == 403
        # A browser without the token sees the refusal; with it, the rest pose.
        page = new_page(local)
        assert "forbidden" in page.inner_text("body")
        page = tools.open_view(new_page, f"{local}?token={token}")
        page.screenshot(path=str(tmp_path / "view_rest.png"))
        assert page.evaluate("puppetView.mode") == "rig"
        # Refused requests are logged on the server (merged), never shown to the pages.
        panels = page.evaluate("puppetView.panels")
        for i in range(30):
            with pytest.raises(urllib.error.HTTPError):
                urllib.request.urlopen(f"{local}probe{i}", timeout=30)
        tools.wait_js(page, f"puppetView.panels > {panels} + 5")
        assert not any("refused" in n["text"] for n in page.evaluate("puppetView.notices"))
        tx, ty = tools.drag_tail(page)
        tools.wait_until(lambda: tools.is_character(tools.frame_image(page)[ty - 4:ty + 5, tx - 4:tx + 5]),
                         what="the dragged tail")
        page.screenshot(path=str(tmp_path / "view_dragged.png"))
    finally:
        status = view.stop()
    assert status == 0, view.stderr()
    assert "handles: 1" in view.stdout()
    assert "refused / from 127.0.0.1: missing or wrong token" in view.stderr()


def write_take(path, seconds: float = 3.0, rate_hz: float = 100.0, marks=()):
    """A take of the built-in rig whose servos swing: written as the recorder writes.
    marks: (seconds into the take, name) stored as the view's marker button stores them."""
    from puppet.bus import Reading
    from puppet.take.header import take_writer

    rig = builtin()
    ids = rig.servo_map.ids
    writer = take_writer(str(path), rig)
    zero = np.round(rig.servo_map.zero).astype(np.int32)
    for i in range(int(seconds * rate_hz)):
        t = i / rate_hz
        ticks = (zero + 300 * math.sin(2 * math.pi * t / 1.5)).astype(np.int32)
        writer.write(Reading(1_000_000_000 + int(t * 1e9), ids, ticks, np.ones(len(ids), bool)))
    for t, name in marks:
        writer.mark(1_000_000_000 + int(t * 1e9), name)
    writer.close()


def test_play_view_pauses_and_seeks(new_page, tools, tmp_path):
    take = tmp_path / "swing.mcap"
    write_take(take)
    play = tools.PuppetProcess(["play", str(take), "--view", str(tools.free_port())], tmp_path)
    try:
        page = tools.open_view(new_page, play)
        assert page.is_visible("#playback")
        tools.wait_js(page, "puppetView.playback && puppetView.playback.position_s > 0.3")
        page.click("#pause")
        paused = tools.wait_js(page, "puppetView.playback.paused && puppetView.playback")
        seq = page.evaluate("puppetView.panel.t_s")
        tools.wait_js(page, f"puppetView.panel.t_s > {seq} + 0.5")
        assert page.evaluate("puppetView.playback.position_s") == paused["position_s"]
        page.evaluate("const s = document.getElementById('scrub'); s.value = '2.5';"
                      "s.dispatchEvent(new Event('input'));")
        tools.wait_js(page, "Math.abs(puppetView.playback.position_s - 2.5) < 0.01")
        page.select_option("#speed", "0.5")
        page.click("#pause")  # play on, at half speed, to the end
        tools.wait_js(page, "puppetView.playback.speed === 0.5 && puppetView.playback.paused "
                            "&& puppetView.playback.position_s === puppetView.playback.duration_s")
    finally:
        status = play.stop()
    assert status == 0, play.stderr()
    assert "Traceback" not in play.stderr()


def test_play_view_shows_the_takes_marks_and_plays_again_from_the_end(new_page, tools, tmp_path):
    take = tmp_path / "marked.mcap"
    write_take(take, marks=[(0.5, "lift"), (2.0, "a rather long mark name that must not overflow")])
    play = tools.PuppetProcess(["play", str(take), "--view", str(tools.free_port())], tmp_path)
    try:
        page = tools.open_view(new_page, play)
        tools.wait_js(page, "puppetView.takeMarks.length === 2")
        ticks = page.evaluate("Array.from(document.querySelectorAll('#take-marks option'), o => Number(o.value))")
        assert ticks == [0.5, 2.0]  # on the slider, at the marks' play times
        buttons = page.locator("#take-mark-list button")
        assert buttons.count() == 2
        assert buttons.nth(0).inner_text().startswith("lift")
        page.click("#pause")
        # Paused: nothing moves, so once the solver settled (the loop renders no frame for a
        # panel period) only a keep-alive frame now and then (it streamed 17-20 frames per
        # second before).
        tools.wait_still(page, "puppetView.panel.playback && puppetView.panel.playback.paused")
        tools.wait_js(page, "puppetView.playback.paused && !puppetView.draft")
        window_s = 1.5 * KEEPALIVE_S
        shown, start = page.evaluate("[puppetView.shown, performance.now()]")
        tools.wait_js(page, f"performance.now() > {start} + {window_s * 1000}")
        assert page.evaluate("puppetView.shown") - shown <= window_s / KEEPALIVE_S + 2
        # A plain click on the character pins nothing (a handle needs a drag of a few pixels).
        bone = page.evaluate("puppetView.bones[Math.floor(puppetView.bones.length / 2)]")
        box = page.locator("#marks").bounding_box()
        scale = box["width"] / page.evaluate("puppetView.width")
        page.mouse.click(box["x"] + (bone["a"][0] + bone["b"][0]) / 2 * scale,
                         box["y"] + (bone["a"][1] + bone["b"][1]) / 2 * scale)
        panels = page.evaluate("puppetView.panels")
        tools.wait_js(page, f"puppetView.panels > {panels} + 5")
        assert page.evaluate("puppetView.handles.length") == 0
        assert page.evaluate("puppetView.lastPick") is None
        buttons.nth(1).click()  # jump to the mark
        tools.wait_js(page, "Math.abs(puppetView.playback.position_s - 2.0) < 0.01")
        buttons.nth(0).click()
        tools.wait_js(page, "Math.abs(puppetView.playback.position_s - 0.5) < 0.01")
        # Scrub to the end, then play: it plays again from the start.
        page.evaluate("const s = document.getElementById('scrub'); s.value = s.max;"
                      "s.dispatchEvent(new Event('input')); s.dispatchEvent(new Event('change'));")
        tools.wait_js(page, "puppetView.playback.position_s >= puppetView.playback.duration_s - 0.01")
        page.click("#pause")
        tools.wait_js(page, "!puppetView.playback.paused && puppetView.playback.position_s > 0.1 "
                            "&& puppetView.playback.position_s < puppetView.playback.duration_s - 0.1")
        assert page.evaluate("document.documentElement.scrollWidth <= innerWidth")
    finally:
        status = play.stop()
    assert status == 0, play.stderr()
    assert "Traceback" not in play.stderr()


def test_live_view_with_record_and_frames_marks_the_take(new_page, tools, tmp_path):
    import hw_sim
    from puppet.take import TakeReader
    from puppet.take.markers import read_markers

    rig = builtin()
    with hw_sim.serve(rig.servo_map.models, motion="wave") as bus:
        live = tools.PuppetProcess(["live", "--rig", str(rig.path), "--port", bus.link,
                                    "--record", "take.mcap", "--frames", "frames", "--fps", "5",
                                    "--view", str(tools.free_port())], tmp_path)
        try:
            page = tools.open_view(new_page, live)
            page.fill("#marker-name", "cue")
            page.click("#marker")
            tools.wait_js(page, "puppetView.markers.some(m => m.name === 'cue')")
        finally:
            status = live.stop()
    assert status == 0, live.stderr()
    assert [name for _, name in read_markers(tmp_path / "take.mcap")] == ["cue"]
    assert len(TakeReader(tmp_path / "take.mcap")) > 10
    assert len(list((tmp_path / "frames").glob("*.png"))) > 0
