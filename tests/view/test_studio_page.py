"""``puppet studio SESSION --demo`` driven as an animator would, in Chromium, by clicks and keys
only after the start command: two shots, three takes (count-in, record, stop, marker), circle,
note, lock, delete and restore, review (play, scrub), a looping clip, export of the circled
take; then the session folder checked from outside (``puppet session list``, ``puppet play``
of a take, the glTF read back). Screenshots at 390, 1280 and 2560 px into the test's folder.
Bad input: a second studio refused naming the first, a take removed behind the studio's back
listed as missing, a damaged index rebuilt, a read-only session folder refused naming it."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pygltflib
import pytest

from puppet.rig import builtin
from puppet.studio import SessionFolder

STUDIO_WAIT_S = 120.0


def _studio(tools, folder: Path, cwd: Path, *extra: str, size=("320", "240")):
    """``puppet studio FOLDER --demo`` at ``size`` (320x240 where the frames are no subject:
    less render CPU beside the simulated bus)."""
    return tools.PuppetProcess(["studio", str(folder), "--demo", "--size", *size,
                                "--address", f"127.0.0.1:{tools.free_port()}", *extra], cwd)


def _open(new_page, process, tools, width=1280, height=800):
    return tools.open_studio(new_page, process, width, height, STUDIO_WAIT_S)


def _said(page, tools, text: str):
    """Wait until the page's studio line says ``text``; returns it."""
    return tools.wait_js(page, f"puppetView.studio && puppetView.studio.said && "
                               f"puppetView.studio.said.text.includes({json.dumps(text)}) && "
                               "puppetView.studio.said.text", STUDIO_WAIT_S)


def _takes(page, shot: str) -> list:
    return page.evaluate(f"(puppetView.studio.shots.find(s => s.name === {json.dumps(shot)}) "
                         "|| {takes: []}).takes")


def _record(page, tools, shot: str, number: int, count_in: str = "1"):
    """Count-in, record until readings came, a marker, stop: take ``number`` of ``shot``."""
    page.get_by_label("count-in seconds").select_option(count_in)
    page.get_by_role("button", name="● record", exact=True).click()
    if count_in != "0":  # the countdown shows (a loaded machine may only catch its end)
        tools.wait_js(page, "!document.getElementById('countdown').hidden || "
                            "(puppetView.recording.on && puppetView.recording.starts_in_s === 0)",
                      STUDIO_WAIT_S)
        shown = page.evaluate("document.getElementById('countdown').hidden ? null : "
                              "document.getElementById('countdown').innerText")
        assert shown is None or shown in {"1", "2", "3", "4", "5"}, shown
    tools.wait_js(page, "puppetView.recording.on && puppetView.recording.starts_in_s === 0 && "
                        "puppetView.recording.readings > 150", STUDIO_WAIT_S)
    page.get_by_role("button", name="marker", exact=True).click()
    tools.wait_js(page, "puppetView.markers.length > 0", STUDIO_WAIT_S)
    page.get_by_role("button", name="■ stop", exact=True).click()
    _said(page, tools, f"recorded {shot} take {number}")
    takes = _takes(page, shot)
    assert [t["number"] for t in takes][-1] == number
    return takes[-1]


def _seam_and_median_step(gltf, bones) -> tuple[float, float]:
    """(the largest rotation of ``bones`` from the animation's last frame to its first, the
    median over frames of their largest from one frame to the next), radians, from a glTF's
    keys (angles by atan2 of the relative quaternion: exact to float32's storage)."""
    import numpy as np

    blob = gltf.binary_blob()
    quats = []
    for channel in gltf.animations[0].channels:
        if channel.target.path != "rotation" or gltf.nodes[channel.target.node].name not in bones:
            continue
        sampler = gltf.animations[0].samplers[channel.sampler]
        accessor = gltf.accessors[sampler.output]
        view = gltf.bufferViews[accessor.bufferView]
        quats.append(np.frombuffer(blob, np.float32, accessor.count * 4, (view.byteOffset or 0)
                                   + (accessor.byteOffset or 0)).reshape(-1, 4).astype(float))
    q = np.stack(quats)  # (bones, frames, 4) x y z w
    assert len(q) == len(bones), "a bone without rotation keys"

    def angle(a, b):  # of b relative to a: 2 atan2(|xyz of a* b|, |w of a* b|)
        w = (a * b).sum(-1)
        xyz = a[..., 3:] * b[..., :3] - b[..., 3:] * a[..., :3] - np.cross(a[..., :3], b[..., :3])
        return 2 * np.arctan2(np.linalg.norm(xyz, axis=-1), np.abs(w))

    steps = angle(q[:, :-1], q[:, 1:]).max(axis=0)
    return float(angle(q[:, -1], q[:, 0]).max()), float(np.median(steps))


RECORDING_SEEN_JS = """(() => {  // every recording state the page shows, [on, path], in order
  window.recordingSeen = [];
  const shown = window.setRecording;
  window.setRecording = (...args) => {
    shown(...args);
    recordingSeen.push([puppetView.recording.on, puppetView.recording.path]);
  };
})()"""


def _never_back(page):
    """The page's recording state only went forward: each state it showed (on or off, of a
    take's path) came in one run; a panel sent before a start or stop and delivered after it
    (the panel goes after the messages) is not shown over the newer state."""
    runs = []
    for state in page.evaluate("recordingSeen"):
        if not runs or runs[-1] != state:
            runs.append(state)
    assert len(runs) == len({tuple(r) for r in runs}), runs


def _select(page, shot: str, number: int):
    page.get_by_label("current shot").select_option(label=shot)
    page.get_by_role("button", name=f"{shot} take {number}").click()
    assert page.get_by_role("button", name=f"{shot} take {number}").get_attribute("aria-pressed") == "true"


def test_a_session_of_two_shots_and_three_takes(new_page, tools, tmp_path):
    folder = tmp_path / "shoot"
    process = _studio(tools, folder, tmp_path, size=("640", "480"))  # the ghost's magenta seen
    try:
        page = _open(new_page, process, tools)
        page.evaluate(RECORDING_SEEN_JS)
        assert page.locator("#instruction").inner_text().startswith("Name a shot")
        assert page.get_by_role("button", name="rename shot", exact=True).is_disabled()

        page.get_by_label("shot name").fill("walk")
        page.get_by_role("button", name="new shot", exact=True).click()
        _said(page, tools, "new shot 'walk'")
        first = _record(page, tools, "walk", 1)
        assert first["rig"] and first["duration_s"] > 0 and first["date"]
        _record(page, tools, "walk", 2)
        page.get_by_label("shot name").fill("run")
        page.get_by_role("button", name="new shot", exact=True).click()
        _said(page, tools, "new shot 'run'")
        _record(page, tools, "run", 1, count_in="0")
        _never_back(page)

        # circle walk 1, note and lock walk 2; a locked take's edits are refused
        _select(page, "walk", 1)
        page.get_by_role("button", name="circle", exact=True).click()
        _said(page, tools, "take 1 circled")
        _select(page, "walk", 2)
        page.get_by_label("note", exact=True).fill("too fast at the turn")
        page.get_by_role("button", name="save note", exact=True).click()
        _said(page, tools, "take 2: note saved")
        page.get_by_role("button", name="lock", exact=True).click()
        _said(page, tools, "locked: read-only")
        assert page.get_by_role("button", name="delete", exact=True).is_disabled()
        assert page.get_by_role("button", name="save note", exact=True).is_disabled()
        assert "locked" in page.get_by_role("button", name="walk take 2, locked", exact=True).inner_text()

        # delete run 1 into the trash, then restore it
        _select(page, "run", 1)
        page.get_by_role("button", name="delete", exact=True).click()
        _said(page, tools, "moved into the session's trash")
        assert (folder / "trash" / "run" / "take001.mcap").is_file()
        assert page.get_by_role("button", name="restore", exact=True).is_enabled()
        page.get_by_role("button", name="restore", exact=True).click()
        _said(page, tools, "restored from the trash")
        assert (folder / "takes" / "run" / "take001.mcap").is_file()
        page.get_by_label("shot name").fill("sprint")  # the current shot renamed: no file moves
        page.get_by_role("button", name="rename shot", exact=True).click()
        _said(page, tools, "shot 'run' is now 'sprint'")
        assert page.get_by_label("current shot").locator("option:checked").inner_text() == "sprint"
        assert (folder / "takes" / "run" / "take001.mcap").is_file()

        # review walk 1: play, scrub, a looping clip
        _select(page, "walk", 1)
        page.get_by_role("button", name="review", exact=True).click()
        _said(page, tools, "reviewing walk take 1")
        tools.wait_js(page, "puppetView.playback && !document.getElementById('playback').hidden",
                      STUDIO_WAIT_S)
        page.get_by_role("button", name="play", exact=True).click()
        tools.wait_js(page, "puppetView.playback.position_s > 0.2", STUDIO_WAIT_S)
        page.get_by_role("button", name="pause", exact=True).click()
        held = tools.wait_js(page, "puppetView.playback.paused && puppetView.playback.position_s",
                             STUDIO_WAIT_S)
        seq = page.evaluate("puppetView.shownSeq")
        tools.wait_js(page, f"puppetView.shownSeq > {seq} + 3", STUDIO_WAIT_S)
        assert page.evaluate("puppetView.playback.position_s") == held  # paused: it holds
        page.get_by_label("speed").select_option("2")
        tools.wait_js(page, "puppetView.playback.speed === 2", STUDIO_WAIT_S)
        page.get_by_role("button", name="play", exact=True).click()
        tools.wait_js(page, "puppetView.playback.paused && puppetView.playback.position_s >= "
                            "puppetView.playback.duration_s - 0.05", STUDIO_WAIT_S)  # its end
        duration = page.evaluate("puppetView.playback.duration_s")
        # the take's marks (the marker pressed while recording): a click jumps there
        mark = page.locator("#take-mark-list button")
        tools.wait_js(page, "document.querySelectorAll('#take-mark-list button').length === 1",
                      STUDIO_WAIT_S)
        assert mark.inner_text().startswith("mark · ")
        mark_s = page.evaluate("puppetView.playback.markers[0].t_s")
        assert 0 < mark_s < duration
        mark.click()
        tools.wait_js(page, f"Math.abs(puppetView.playback.position_s - {mark_s}) < 0.05",
                      STUDIO_WAIT_S)
        assert duration > 0.5
        scrub = page.get_by_label("play position")
        scrub.fill(str(round(duration * 0.2, 3)))
        tools.wait_js(page, f"puppetView.playback.paused && Math.abs(puppetView.playback.position_s - "
                            f"{duration * 0.2}) < 0.05", STUDIO_WAIT_S)
        page.get_by_role("button", name="set in", exact=True).click()
        scrub.fill(str(round(duration * 0.8, 3)))
        tools.wait_js(page, f"Math.abs(puppetView.playback.position_s - {duration * 0.8}) < 0.05",
                      STUDIO_WAIT_S)
        page.get_by_role("button", name="set out", exact=True).click()
        page.get_by_label("clip name").fill("cycle")
        page.get_by_label("loop").check()
        page.get_by_role("button", name="make clip", exact=True).click()
        _said(page, tools, "loop 'cycle'")

        # compare: walk 2 as a magenta ghost over walk 1 (the frames change, tinted)
        seq = page.evaluate("puppetView.shownSeq")
        _select(page, "walk", 2)
        page.get_by_role("button", name="compare", exact=True).click()
        _said(page, tools, "comparing walk take 2")
        tools.wait_js(page, f"puppetView.shownSeq > {seq} + 2", STUDIO_WAIT_S)
        legend = page.get_by_role("list", name="ghost colours").inner_text()
        assert "compared take" in legend and "previous key" in legend
        image = tools.frame_image(page)
        magenta = ((image[..., 0] > image[..., 1] + 60) & (image[..., 2] > image[..., 1] + 60)).sum()
        assert magenta > 200, magenta
        # every take's facts start at one place, a take with clips too (its rows stay aligned)
        xs = page.evaluate("Array.from(document.querySelectorAll('#takes button.take "
                           ".facts:not(.clips)'), e => Math.round(e.getBoundingClientRect().x))")
        assert len(xs) == 2 and len(set(xs)) == 1, xs
        page.get_by_role("button", name="compare off", exact=True).click()
        _said(page, tools, "compare off")
        page.get_by_role("button", name="live", exact=True).click()
        _said(page, tools, "live: the puppet")

        # export the circled take as glTF
        page.get_by_role("button", name="export circled", exact=True).click()
        said = _said(page, tools, "exported 1 circled take(s) and 1 clip(s)")
        assert "failed" not in said

        shown = page.evaluate("puppetView.studio.shots")
        out = tmp_path
        for width in (390, 1280, 2560):
            page.set_viewport_size({"width": width, "height": 900 if width < 2000 else 1440})
            page.wait_for_timeout(300)  # a layout pass (nothing is asserted on it)
            page.screenshot(path=str(out / f"studio-{width}.png"), full_page=True)
            box = page.locator("#stage").bounding_box()
            assert box["width"] > (300 if width == 390 else 700 if width == 1280 else 1300)
    finally:
        assert process.stop() == 0, process.stderr()

    # ---- the session folder from outside ----
    session = SessionFolder.read(folder)
    listing = session.listing()
    by_name = {s["name"]: s for s in listing["shots"]}
    assert set(by_name) == {"walk", "sprint"}
    assert [t["number"] for t in by_name["walk"]["takes"]] == [1, 2]
    assert [t["number"] for t in by_name["sprint"]["takes"]] == [1]
    walk = {t["number"]: t for t in by_name["walk"]["takes"]}
    assert walk[1]["circled"] and not walk[2]["circled"]
    assert walk[2]["note"] == "too fast at the turn" and walk[2]["locked"]
    assert [(s["name"], s["loop"]) for s in walk[1]["segments"]] == [("cycle", True)]
    assert not by_name["sprint"]["takes"][0]["trashed"]
    page_walk = next(s for s in shown if s["name"] == "walk")
    assert [t["note"] for t in page_walk["takes"]] == [t["note"] for t in by_name["walk"]["takes"]]
    glb = folder / "exports" / "walk" / "take001.glb"
    gltf = pygltflib.GLTF2().load_binary(str(glb))
    assert gltf.animations and gltf.animations[0].channels
    clip = pygltflib.GLTF2().load_binary(str(folder / "exports" / "walk" / "take001.cycle.glb"))
    frames = clip.scenes[clip.scene or 0].extras
    whole = gltf.scenes[gltf.scene or 0].extras
    assert frames["puppet_frame_end"] < whole["puppet_frame_end"]  # the clip: 60 % of the take
    # the loop's seam, in the file: its last frame to its first jumps no more than the clip's
    # median frame-to-frame motion (a performance's clip: the out point may fall in a fast move),
    # on the joints the blend turns (the servos'; the solver fills the others from its history)
    sensed = {servo.joint for servo in builtin().servo_map.servos}
    seam, median = _seam_and_median_step(clip, sensed)
    assert seam <= median + 1e-5, (seam, median)  # (float32 keys)
    video = tmp_path / "walk1.mp4"
    run = subprocess.run([*tools.PUPPET, "play", str(folder / "takes" / "walk" / "take001.mcap"),
                          "--out", str(video)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert video.stat().st_size > 1000


def test_a_second_studio_is_refused_and_a_removed_take_is_listed_missing(new_page, tools,
                                                                         tmp_path):
    folder = tmp_path / "shoot"
    process = _studio(tools, folder, tmp_path)
    try:
        page = _open(new_page, process, tools)
        page.get_by_label("shot name").fill("walk")
        page.get_by_role("button", name="new shot", exact=True).click()
        _said(page, tools, "new shot 'walk'")
        _record(page, tools, "walk", 1, count_in="0")

        second = subprocess.run([*tools.PUPPET, "studio", str(folder), "--demo", "--address",
                                 f"127.0.0.1:{tools.free_port()}"], capture_output=True,
                                text=True, timeout=300, cwd=tmp_path)
        assert second.returncode == 1
        assert second.stderr.startswith("Error: ") and "Traceback" not in second.stderr
        assert f"pid {process.proc.pid}" in second.stderr and "studio" in second.stderr
        assert "view: http" not in second.stderr  # refused before the page or the bus

        (folder / "takes" / "walk" / "take001.mcap").unlink()  # behind the studio's back
        tools.wait_js(page, "puppetView.studio.shots[0].takes[0].status === 'missing'",
                      STUDIO_WAIT_S)
        _select(page, "walk", 1)
        assert "missing" in page.get_by_role("button", name="walk take 1, missing").inner_text()
        assert page.get_by_role("button", name="review", exact=True).is_disabled()
        assert page.get_by_role("button", name="export take", exact=True).is_disabled()
        _record(page, tools, "walk", 2, count_in="0")  # the studio goes on
    finally:
        assert process.stop() == 0, process.stderr()


def test_a_damaged_index_is_rebuilt_saying_so(new_page, tools, tmp_path):
    folder = tmp_path / "shoot"
    process = _studio(tools, folder, tmp_path)
    try:
        page = _open(new_page, process, tools)
        page.get_by_label("shot name").fill("walk")
        page.get_by_role("button", name="new shot", exact=True).click()
        _said(page, tools, "new shot 'walk'")
        _record(page, tools, "walk", 1, count_in="0")
    finally:
        assert process.stop() == 0, process.stderr()
    (folder / "session.json").write_text('{"shots": [ damaged')
    process = _studio(tools, folder, tmp_path)
    try:
        assert "rebuilt" in process.stderr() and "session.json" in process.stderr()
        page = _open(new_page, process, tools)
        tools.wait_js(page, "puppetView.notices.some(n => n.text.includes('rebuilt'))",
                      STUDIO_WAIT_S)
        takes = page.evaluate("puppetView.studio.shots.flatMap(s => s.takes)")
        assert [t["number"] for t in takes] == [1] and takes[0]["status"] == "ok"
    finally:
        assert process.stop() == 0, process.stderr()
    assert list((folder / "trash").glob("session.damaged-*.json"))


def test_a_read_only_session_folder_fails_before_recording(tools, tmp_path):
    folder = tmp_path / "shoot"
    folder.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(folder)],
                             capture_output=True, text=True, timeout=60)
    if mounted.returncode != 0:
        pytest.fail(f"cannot mount a tmpfs (the test needs root): {mounted.stderr}")
    try:
        subprocess.run(["mount", "-o", "remount,ro", str(folder)], check=True, timeout=60)
        run = subprocess.run([*tools.PUPPET, "studio", str(folder), "--demo", "--address",
                              f"127.0.0.1:{tools.free_port()}"], capture_output=True, text=True,
                             timeout=300, cwd=tmp_path)
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=True, timeout=60)
    assert run.returncode == 1
    assert run.stderr.startswith("Error: ") and str(folder) in run.stderr, run.stderr
    assert "Traceback" not in run.stderr and "view: http" not in run.stderr


def _click_track(path: Path, seconds: float = 8.0, rate: int = 22050) -> Path:
    """A mono 16-bit WAV: silence with a click every second (known times)."""
    import wave

    import numpy as np

    samples = np.zeros(int(seconds * rate), np.int16)
    for k in range(int(seconds)):
        samples[k * rate: k * rate + 200] = 20000
    with wave.open(str(path), "wb") as out:
        out.setnchannels(1)
        out.setsampwidth(2)
        out.setframerate(rate)
        out.writeframes(samples.tobytes())
    return path


def test_the_shot_sound_under_the_timeline_heard_from_the_take_time_0(new_page, tools, tmp_path):
    from puppet.sound import file_sha256
    from puppet.take import TakeReader

    track = _click_track(tmp_path / "clicks.wav")
    folder = tmp_path / "shoot"
    process = _studio(tools, folder, tmp_path, "--sound", str(track))
    try:
        page = _open(new_page, process, tools)
        assert page.get_by_role("img", name="sound waveform").is_visible()
        page.get_by_label("shot name").fill("lines")
        page.get_by_role("button", name="new shot", exact=True).click()  # a gesture: audio on
        _said(page, tools, "new shot 'lines'")
        tools.wait_js(page, "puppetView.audio.buffer !== null", STUDIO_WAIT_S)
        assert abs(page.evaluate("puppetView.audio.buffer.duration") - 8.0) < 0.01
        _record(page, tools, "lines", 1, count_in="2")
        start = page.evaluate("puppetView.audio.starts[0]")
        # scheduled at the count-in's end (what was left of 2 s when the page heard of it)
        assert start["offset_s"] == 0 and start["rate"] == 1
        assert 0.5 < start["when"] - start["now"] <= 2.0, start
        shot = page.evaluate("puppetView.studio.shots[0].key")

        _select(page, "lines", 1)
        page.get_by_role("button", name="review", exact=True).click()
        _said(page, tools, "reviewing lines take 1")
        stored = page.evaluate("puppetView.studio.reviewing.sound_offset_s")
        # the sound's time at the first reading: just after the count-in (later on a loaded host)
        assert stored is not None and 0 <= stored < 1.0
        count = page.evaluate("puppetView.audio.starts.length")
        page.get_by_role("button", name="play", exact=True).click()
        tools.wait_js(page, f"puppetView.audio.starts.length > {count}", STUDIO_WAIT_S)
        heard = page.evaluate("puppetView.audio.starts.at(-1)")
        assert heard["piece_s"] is None and heard["rate"] == 1
        assert abs(heard["offset_s"] - stored) < 0.5  # from the play position (near 0)
        tools.wait_js(page, "puppetView.playback.paused", STUDIO_WAIT_S)
        count = page.evaluate("puppetView.audio.starts.length")
        page.get_by_label("play position").fill("1.0")
        tools.wait_js(page, f"puppetView.audio.starts.length > {count}", STUDIO_WAIT_S)
        piece = page.evaluate("puppetView.audio.starts.at(-1)")
        assert piece["piece_s"] == pytest.approx(0.15) and piece["offset_s"] == pytest.approx(stored + 1.0)
        drawn = page.evaluate("""(() => { const c = document.getElementById('waveform');
            const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;
            const top = c.width * 4 * Math.floor(c.height / 4);  // the top quarter: only the clicks reach it
            for (let i = 0; i < top; i += 4) if (d[i] > 150 && d[i + 1] > 150) n++; return n; })()""")
        assert drawn >= 8  # the clicks reach it (8 of them), silence never does
    finally:
        assert process.stop() == 0, process.stderr()
    take = folder / "takes" / shot / "take001.mcap"
    ref = TakeReader(take).metadata.sound
    assert ref.sha256 == file_sha256(track) and ref.rate == 22050
    assert track.read_bytes()[:4] == b"RIFF"  # the input untouched


def test_a_sound_chosen_on_the_page(new_page, tools, tmp_path):
    from puppet.sound import file_sha256
    from puppet.take import TakeReader

    folder = tmp_path / "shoot"
    process = _studio(tools, folder, tmp_path)
    try:
        page = _open(new_page, process, tools)
        assert not page.get_by_role("img", name="sound waveform").is_visible()
        (folder / "sounds").mkdir()
        track = _click_track(folder / "sounds" / "line one.wav", seconds=4.0)
        tools.wait_js(page, "puppetView.studio.sounds.includes('line one.wav')", STUDIO_WAIT_S)
        page.get_by_label("shot sound").select_option("line one.wav")
        _said(page, tools, "sound line one.wav")
        assert page.get_by_role("img", name="sound waveform").is_visible()
        page.get_by_label("shot name").fill("lines")
        page.get_by_role("button", name="new shot", exact=True).click()
        tools.wait_js(page, "puppetView.audio.buffer !== null", STUDIO_WAIT_S)
        assert abs(page.evaluate("puppetView.audio.buffer.duration") - 4.0) < 0.01
        _record(page, tools, "lines", 1, count_in="1")
        shot = page.evaluate("puppetView.studio.shots[0].key")
    finally:
        assert process.stop() == 0, process.stderr()
    ref = TakeReader(folder / "takes" / shot / "take001.mcap").metadata.sound
    assert ref.sha256 == file_sha256(track)


EXPORTS_SEEN_JS = """(() => { window.exportsSeen = []; const shown = handlers.studio;
  handlers.studio = m => { shown(m); const bar = document.getElementById('export-progress');
    if (m.export) exportsSeen.push({running: m.export.running, done: m.export.done,
                                    total: m.export.total, value: bar.value, max: bar.max}); }; })()"""


def _video_frames_and_fps(path: Path) -> tuple[int, float]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    count = sum(1 for _ in reader)
    return count, float(meta["fps"])


def _export_on_page(page, tools, button: str) -> list:
    """Press an export button; wait until the export ended. Returns the progress the page was
    sent and showed ({running, done, total, value, max} per studio message), this export's."""
    before = page.evaluate("exportsSeen.length")
    page.get_by_role("button", name=button, exact=True).click()
    tools.wait_js(page, f"exportsSeen.length > {before} && !exportsSeen.at(-1).running",
                  STUDIO_WAIT_S * 3)
    return page.evaluate(f"exportsSeen.slice({before})")


def test_an_export_from_the_page_at_the_shots_rate_with_keys_and_progress(new_page, tools,
                                                                         tmp_path):
    """A 24 fps shot (``--fps 24``) exports at 24 unless the page says otherwise; the keys
    reduction field is the export's ``--keys``; BVH and MP4 beside glTF; the progress bar shows the
    export running, then done; outputs in the session's exports/<shot>/."""
    folder = tmp_path / "shoot"
    process = _studio(tools, folder, tmp_path, "--fps", "24")
    try:
        page = _open(new_page, process, tools)
        page.evaluate(EXPORTS_SEEN_JS)
        page.get_by_label("shot name").fill("walk")
        page.get_by_role("button", name="new shot", exact=True).click()
        _said(page, tools, "new shot 'walk'")
        _record(page, tools, "walk", 1, count_in="0")
        _select(page, "walk", 1)
        page.get_by_role("checkbox", name="BVH").check()
        page.get_by_role("checkbox", name="MP4").check()
        page.get_by_label("keys reduction degrees").fill("0.5")
        seen = _export_on_page(page, tools, "export take")
        said = _said(page, tools, "exported walk take 1")
        assert said.endswith(str(folder / "exports")), said
        assert seen[0]["running"] and seen[0]["done"] == 0 and seen[0]["value"] == 0, seen
        last = seen[-1]
        assert last["done"] == last["total"] == last["value"] == last["max"] == 1, seen
        glb = folder / "exports" / "walk" / "take001.glb"
        gltf = pygltflib.GLTF2().load_binary(str(glb))
        extras = gltf.scenes[gltf.scene or 0].extras
        assert extras["puppet_fps"] == 24.0 and extras["puppet_timecode_rate"] == "24"
        frames = extras["puppet_frame_end"]
        counts = [gltf.accessors[s.input].count for s in gltf.animations[0].samplers]
        assert max(counts) <= frames and min(counts) < frames / 2, (frames, counts)  # reduced
        bvh = (folder / "exports" / "walk" / "take001.bvh").read_text()
        assert "Frame Time: 0.041666667" in bvh and f"Frames: {frames}" in bvh
        video = folder / "exports" / "walk" / "take001.mp4"  # the picture, at the shot's rate
        assert _video_frames_and_fps(video) == (frames, 24.0)

        page.get_by_role("checkbox", name="BVH").uncheck()
        page.get_by_role("checkbox", name="MP4").uncheck()
        page.get_by_label("keys reduction degrees").fill("")
        page.get_by_label("export fps").fill("12")  # told otherwise: at 12, every frame
        _export_on_page(page, tools, "export take")
        _said(page, tools, "exported walk take 1")
    finally:
        assert process.stop() == 0, process.stderr()
    gltf = pygltflib.GLTF2().load_binary(str(glb))
    extras = gltf.scenes[gltf.scene or 0].extras
    assert extras["puppet_fps"] == 12.0
    counts = {gltf.accessors[s.input].count for s in gltf.animations[0].samplers}
    assert counts == {extras["puppet_frame_end"]}
    assert abs(extras["puppet_frame_end"] - frames / 2) <= 1


CONTROLS_JS = """(() => Array.from(document.querySelectorAll('button, input, select'))
  .filter(el => el.offsetParent !== null && el.type !== 'hidden')
  .map(el => { const box = el.getBoundingClientRect();
    const name = (el.getAttribute('aria-label') || (el.labels && el.labels.length ? el.labels[0].textContent : '')
                  || el.textContent || el.title || el.placeholder || '').trim();
    return { id: el.id || el.outerHTML.slice(0, 60), w: box.width, h: box.height, name,
             disabled: el.disabled, opacity: Number(getComputedStyle(el).opacity) }; }))()"""


@pytest.fixture(scope="module")
def fresh_studio(tools, tmp_path_factory):
    """One ``puppet studio --demo`` on a new session, shared by the tests that find it as it
    started: the late-script test (which changes nothing) and the first-timer's (which needs no
    shot yet, and adds one). It must stop with exit 0 and no traceback."""
    folder = tmp_path_factory.mktemp("fresh_studio")
    process = _studio(tools, folder / "shoot", folder)
    yield process
    assert process.stop() == 0, process.stderr()
    assert "Traceback" not in process.stderr()


def test_the_studio_shows_when_its_script_loads_after_the_first_messages(new_page, tools,
                                                                       fresh_studio):
    """studio.js held back 1.5 s (a slow fetch, a loaded machine): the page connects once every
    script has run, so the snapshot reaches the studio's handler (it went to the plain view's,
    and the page never showed its studio: a CI failure)."""
    import time

    page = new_page()

    def slow(route):
        time.sleep(1.5)  # the stimulus: a script that arrives late
        route.continue_()

    page.route("**/static/studio.js", slow)
    page.goto(fresh_studio.url)
    tools.wait_js(page, "puppetView.shownSeq >= 0", STUDIO_WAIT_S)
    tools.wait_js(page, "puppetView.studio !== null && puppetView.studio.shots !== undefined",
                  STUDIO_WAIT_S)
    assert page.is_visible("#studio")


def test_a_first_timer_can_use_the_page(new_page, tools, fresh_studio, tmp_path):
    """Every control named and at least 24 x 24 px, disabled ones look disabled, joint names
    whole at 1024 px, no layout jump when the status line changes, one instruction line."""
    page = _open(new_page, fresh_studio, tools, width=1024, height=768)
    controls = page.evaluate(CONTROLS_JS)
    assert len(controls) > 20
    unnamed = [c["id"] for c in controls if not c["name"]]
    assert not unnamed, unnamed
    small = [(c["id"], c["w"], c["h"]) for c in controls if c["w"] < 24 or c["h"] < 24]
    assert not small, small
    disabled = [c for c in controls if c["disabled"]]
    assert disabled and all(c["opacity"] <= 0.5 for c in disabled)
    assert all(c["opacity"] == 1 for c in controls if not c["disabled"])
    tools.wait_js(page, "document.querySelectorAll('#servos tbody tr').length > 0", STUDIO_WAIT_S)
    cut = page.evaluate("""Array.from(document.querySelectorAll('#servos tbody td:nth-child(2)'))
        .filter(td => td.scrollWidth > td.clientWidth + 1).map(td => td.textContent)""")
    assert not cut, cut
    instruction = page.get_by_role("status").filter(has_text="Name a shot")
    assert instruction.count() == 1
    stage = page.locator("#stage").bounding_box()
    takes = page.locator("#takes").bounding_box()
    page.get_by_label("shot name").fill("")
    page.get_by_role("button", name="new shot", exact=True).click()  # refused: a long status line
    _said(page, tools, "must not be empty")
    page.get_by_label("shot name").fill("a shot with a name long enough to wrap the status")
    page.get_by_role("button", name="new shot", exact=True).click()
    _said(page, tools, "new shot")
    assert page.locator("#stage").bounding_box() == stage
    assert page.locator("#takes").bounding_box()["y"] == takes["y"]
    assert "refused" not in page.locator("#studio-said").get_attribute("class")
    run = subprocess.run([*tools.PUPPET, "studio", str(tmp_path / "other")], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 1 and "--demo" in run.stderr and "Traceback" not in run.stderr


def test_key_poses_are_a_mode_of_the_studio_page(new_page, tools, tmp_path):
    from puppet.take import TakeReader

    folder = tmp_path / "shoot"
    process = _studio(tools, folder, tmp_path)
    try:
        page = _open(new_page, process, tools)
        page.get_by_label("shot name").fill("poses")
        page.get_by_role("button", name="new shot", exact=True).click()
        _said(page, tools, "new shot 'poses'")
        page.get_by_role("button", name="key poses", exact=True).click()
        _said(page, tools, "key poses for 'poses'")
        assert page.locator("#keys").is_visible()
        assert page.get_by_role("button", name="● record", exact=True).is_disabled()
        for n in (1, 2):
            for _ in range(5):  # a key refused (replies late on a busy host: said) is pressed again
                updates = page.evaluate("puppetView.keysUpdates")
                page.locator("#instruction").click()  # focus off any input: Space is the key
                page.keyboard.press("Space")
                tools.wait_js(page, f"puppetView.keys && (puppetView.keys.keys.length === {n} || "
                                    f"puppetView.keysUpdates > {updates} && "
                                    "puppetView.keys.taken === false)", STUDIO_WAIT_S)
                if page.evaluate(f"puppetView.keys.keys.length === {n}"):
                    break
                assert "came late" in page.evaluate("puppetView.keys.said"), \
                    page.evaluate("puppetView.keys.said")
        page.get_by_role("button", name="done keys", exact=True).click()
        _said(page, tools, "keyed poses take 1 (2 keys)")
        assert not page.locator("#keys").is_visible()
        assert _takes(page, "poses")[0]["status"] == "ok"
        _select(page, "poses", 1)
        page.get_by_role("button", name="review", exact=True).click()
        _said(page, tools, "reviewing poses take 1")
    finally:
        assert process.stop() == 0, process.stderr()
    keys = TakeReader(folder / "takes" / "poses" / "take001.mcap").keys()
    assert [k.frame for k in keys.keys] == [1, 13]
