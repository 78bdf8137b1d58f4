"""The one stop rule, for every live command x every way a run ends (issue one-session).

Each command runs as a user's terminal job (its own process group) and is ended by: the end of
its input or --seconds, one Ctrl-C, two Ctrl-C, SIGTERM, or SIGKILL of its bus reader's child.
The commands: demo, live, record, keys, view, play (--out; --view; --link, with a client of the
link), the page's record button (``demo --view``, a take recording from the page) and the studio
(``studio --demo``, a take recording from its page).
Every cell must give the same outcome: exit 0 and the summary on the signals and the end, exit 1
naming the reader when it is killed; every video asked for closed and playable with its frames;
every take readable with its readings; no traceback; no process of the command left behind; no
temporary file left under a final name.
"""

from __future__ import annotations

import asyncio
import importlib.util
import os
import signal
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path
from urllib.parse import urlsplit

import imageio_ffmpeg
import numpy as np
import pytest

import hw_sim
from puppet.reading import Reading
from puppet.rig import builtin
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeError, TakeReader, TakeWriter
from tests.conftest import group_gone

PATIENCE_S = 60.0
PUPPET = [sys.executable, "-m", "puppet.cli"]

BUS = ("demo", "live", "record", "keys")      # commands with a bus reader child
STOPS = ("end", "ctrl-c", "ctrl-c-twice", "sigterm", "kill-reader")


def _take(path: Path, seconds: float) -> Path:
    rig = builtin()
    k = len(rig.servo_map)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
        for i in range(int(seconds * 100)):
            ticks = (rig.servo_map.zero + 300 * np.sin(0.05 * i + np.arange(k))).astype(np.int32)
            writer.write(Reading(i * 10_000_000, rig.servo_map.ids, ticks, np.ones(k, bool)))
    return path


def _encoding(video: Path):
    """Under way once the video's encoder has its first frame: ffmpeg writes the file's header
    (its hidden partial file, renamed to ``video`` when finished) once the first frame reaches
    it, and the sink starts ffmpeg at the first frame."""
    return lambda: any(p.stat().st_size > 0 for p in video.parent.glob(f"*{video.suffix}")
                       if p.is_file())


def _readings(folder: Path, pattern: str):
    """Under way once a take under ``folder`` (``pattern``) holds a reading: each reading is
    in the file when its write returns (TakeWriter), readable before the take is closed."""
    def holds() -> bool:
        for path in folder.glob(pattern):
            try:
                if path.is_file() and len(TakeReader(path)) > 0:
                    return True
            except (TakeError, OSError):  # its header not all written yet
                pass
        return False
    return holds


def _page_up(stderr: Path):
    def up() -> bool:
        for line in stderr.read_text().splitlines():
            if line.startswith("view: "):
                try:
                    with urllib.request.urlopen(line[6:].strip(), timeout=5) as reply:
                        return reply.status == 200
                except OSError:
                    return False
        return False
    return up


def _page_url(stderr: Path) -> str | None:
    return next((line[6:].strip() for line in stderr.read_text().splitlines()
                 if line.startswith("view: ")), None)


def _press(url: str, message: dict) -> None:
    """Send ``message`` on the page's control socket, as the page's buttons do."""
    import aiohttp

    where = urlsplit(url).netloc

    async def send() -> None:
        async with aiohttp.ClientSession() as client:
            async with client.ws_connect(f"ws://{where}/ws/control?client=contract",
                                         origin=f"http://{where}") as ws:
                await ws.send_json(message)

    # In a thread of its own: a worker that ran a page test before holds Playwright's event loop
    # running in this thread (asyncio.run refuses to start a second one there).
    failed: list[BaseException] = []

    def run() -> None:
        try:
            asyncio.run(send())
        except BaseException as exc:  # handed to the test's thread
            failed.append(exc)

    sender = threading.Thread(target=run, name="press")
    sender.start()
    sender.join()
    if failed:
        raise failed[0]


def _pressed(stderr: Path, message: dict, made: Path, pattern: str):
    """Under way once the page is up, ``message`` pressed on it, and a take under ``made``
    (``pattern``) holds a reading."""
    pressed = []

    def up() -> bool:
        if not pressed:
            if not _page_up(stderr)():
                return False
            _press(_page_url(stderr), message)
            pressed.append(True)
        return _readings(made, pattern)()
    return up


def _link_client():
    spec = importlib.util.spec_from_file_location(
        "contract_link_client", Path(__file__).resolve().parents[1] / "link" / "client.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.Client


def _linked(stderr: Path, video: Path, clients: list):
    """Under way once a client of the link is connected (play --link waits for one) and the
    video has its first frame."""
    def up() -> bool:
        if not clients:
            line = next((x for x in stderr.read_text().splitlines()
                         if x.startswith("link: listening on ")), None)
            if line is None:
                return False
            clients.append(_link_client()(int(line.split()[3].rsplit(":", 1)[1])))
        return _encoding(video)()
    return up


@pytest.fixture(scope="module", name="takes")
def _takes(tmp_path_factory) -> dict[str, Path]:
    """The takes the play cells read (never written to): "short" ends by itself in 2 s, "long"
    (120 s) outlasts every stop."""
    folder = tmp_path_factory.mktemp("takes")
    return {"short": _take(folder / "short.mcap", 2.0), "long": _take(folder / "long.mcap", 120.0)}


SMALL = ["--size", "160", "120"]
"""Small frames where a command takes --size: the image is not what the contract is about."""


def _case(name: str, stop: str, tmp: Path, port: str | None, clients: list, takes: dict):
    """(argv, under_way predicate, video or None, take or None, stdin)."""
    seconds = ["--seconds", "2"] if stop == "end" else []
    video, take = tmp / "v.mp4", tmp / "t.mcap"
    rig = ["--rig", str(BUILTIN_RIG), "--port", str(port)]
    if name == "demo":
        return (["demo", "--out", str(video), *SMALL, *seconds], _encoding(video), video, None, None)
    if name == "live":
        return (["live", *rig, "--record", str(take), "--out", str(video), *seconds],
                _encoding(video), video, take, None)
    if name == "record":
        return (["record", *rig, "--out", str(take), *seconds], _readings(tmp, take.name), None,
                take, None)
    if name == "keys":  # end of input ends a key session; otherwise stdin stays open
        return (["keys", *rig, "--out", str(tmp / "shot.mcap")],
                lambda: "hold a pose" in (tmp / "stdout.txt").read_text(), None, None,
                subprocess.DEVNULL if stop == "end" else subprocess.PIPE)
    if name == "view":
        return (["view", "--address", "127.0.0.1:0", *SMALL, *seconds],
                _page_up(tmp / "stderr.txt"), None, None, None)
    # time to press the button: the page serves before the run's clock starts, and the press
    # takes effect at the run's next frame (a loaded machine's press lands well under a second
    # after the clock starts)
    pressed_seconds = ["--seconds", "5"] if stop == "end" else []
    if name == "view-record":  # the page's record button: a take in the command's folder
        return (["demo", "--view", "127.0.0.1:0", "--out", str(video), *SMALL, *pressed_seconds],
                _pressed(tmp / "stderr.txt", {"type": "record", "on": True}, tmp, "take-*.mcap"),
                video, tmp / "take-*.mcap", None)
    if name == "studio":  # the studio page's record button: take 1 of the session's shot
        return (["studio", "shoot", "--demo", "--address", "127.0.0.1:0", *SMALL, *pressed_seconds],
                _pressed(tmp / "stderr.txt", {"type": "studio", "action": "record", "count_in": 0},
                         tmp / "shoot", "takes/*/*.mcap"),
                None, tmp / "shoot" / "takes" / "*" / "*.mcap", None)
    long = takes["short" if stop == "end" else "long"]
    if name == "play":  # the take's frames as fast as they solve, into the video
        return (["play", str(long), "--out", str(video), "--antialias", "none"],
                _encoding(video), video, None, None)
    if name == "play-link":  # on the clock into a client of the link
        return (["play", str(long), "--link", "127.0.0.1:0", "--out", str(video)],
                _linked(tmp / "stderr.txt", video, clients), video, None, None)
    return (["play", str(long), "--view", "127.0.0.1:0", "--out", str(video)],
            _encoding(video), video, None, None)


def _reader_child(pid: int) -> int | None:
    """The pid of ``pid``'s bus reader child (a spawned interpreter: multiprocessing's spawn_main)."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid and b"spawn_main" in cmdline:
            return int(entry.name)
    return None


CASES = ([(n, s) for n in BUS for s in STOPS] + [("view", s) for s in STOPS if s != "kill-reader"]
         + [("play", s) for s in STOPS if s != "kill-reader"]
         + [("play-view", s) for s in STOPS if s not in ("kill-reader", "end")]  # a take on the page
                                                                                # holds its last frame
         + [("play-link", s) for s in STOPS if s != "kill-reader"]
         + [(n, s) for n in ("view-record", "studio") for s in STOPS])
PRESSED = ("play-link", "view-record", "studio")
"""Cases under way only once the test did its part (a client connected, a button pressed),
also when the run ends by itself."""


@pytest.mark.parametrize("name, stop", CASES, ids=[f"{n}-{s}" for n, s in CASES])
def test_every_command_keeps_what_it_made_on_every_way_out(name, stop, tmp_path, wait_until, takes):
    rig = builtin()
    with hw_sim.serve(dict(rig.servo_map.models), motion="wave") as bus:
        clients: list = []
        argv, under_way, video, take, stdin = _case(name, stop, tmp_path, bus.port, clients, takes)
        err_path, out_path = tmp_path / "stderr.txt", tmp_path / "stdout.txt"
        err_path.write_text("")
        out_path.write_text("")
        with open(err_path, "w") as err, open(out_path, "w") as stdout:
            proc = subprocess.Popen([*PUPPET, *argv], stdin=stdin, stdout=stdout,
                                    stderr=err, text=True, process_group=0, cwd=tmp_path)
            try:
                if stop != "end" or name in PRESSED:
                    wait_until(lambda: proc.poll() is not None or under_way(), what=f"{name} under way")
                if stop != "end":
                    assert proc.poll() is None, err_path.read_text()
                    if stop == "ctrl-c":
                        os.killpg(proc.pid, signal.SIGINT)
                    elif stop == "ctrl-c-twice":
                        os.killpg(proc.pid, signal.SIGINT)
                        os.killpg(proc.pid, signal.SIGINT)
                    elif stop == "sigterm":
                        os.killpg(proc.pid, signal.SIGTERM)
                    else:
                        child = wait_until(lambda: _reader_child(proc.pid), what="the reader child")
                        os.kill(child, signal.SIGKILL)
                proc.communicate(timeout=2 * PATIENCE_S)
            finally:
                if proc.poll() is None:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                for client in clients:
                    client.close()
    stderr, out = err_path.read_text(), out_path.read_text()
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    assert "Aborted" not in stderr, stderr
    if stop == "kill-reader":
        assert proc.returncode == 1, stderr
        assert "Error:" in stderr and "reader process" in stderr, stderr
    else:
        assert proc.returncode == 0, stderr
        assert "faults seen" in out, out  # the summary
    wait_until(lambda: group_gone(proc.pid), what="every process of the command ended")
    if video is not None:
        frames, _ = imageio_ffmpeg.count_frames_and_secs(str(video))  # playable: it has its index
        assert frames > 0
    if take is not None:
        takes = sorted(tmp_path.glob(str(take.relative_to(tmp_path)))) if "*" in str(take) else [take]
        assert takes, f"no take at {take}"
        for path in takes:
            assert len(TakeReader(path)) > 0, path
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    assert [str(p) for p in tmp_path.rglob("*") if ".partial" in p.name] == []  # the studio's too


def _catches_sigterm(pid: int) -> bool:
    """True once ``pid`` catches SIGTERM: the command line's first statement ran
    (``puppet.session.signals.early``; Python itself leaves SIGTERM at its default)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = int(next(line for line in status.splitlines() if line.startswith("SigCgt:")).split()[1], 16)
    return bool(caught & (1 << (signal.SIGTERM - 1)))


@pytest.mark.parametrize("after_s", [0.0, 0.3, 1.0])
def test_ctrl_c_during_start_up_stops_cleanly_with_a_summary(after_s, tmp_path, wait_until):
    """From the command line's first statement on (imports, rig, simulated bus, pipeline), a
    Ctrl-C ends the run with its summary and exit 0: no traceback, no 'Aborted!'."""
    import time

    video = tmp_path / "v.mp4"
    proc = subprocess.Popen([*PUPPET, "demo", "--out", str(video), "--seconds", "30"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            process_group=0, cwd=tmp_path)
    try:
        wait_until(lambda: proc.poll() is not None or _catches_sigterm(proc.pid),
                   what="the command line's handlers")
        time.sleep(after_s)  # the stimulus's moment within start-up, not a wait for a state
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=2 * PATIENCE_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "Aborted" not in err, err
    assert "faults seen" in out, out
    wait_until(lambda: group_gone(proc.pid), what="every process of the command ended")
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_killed_demo_leaves_no_simulated_bus_holding_its_page(tmp_path, wait_until):
    """SIGKILL of `puppet demo --view` (its process alone): the simulated bus it forked ends
    with it (its end of the control pipe closes) and the page's port is free again at once."""
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    proc = subprocess.Popen([*PUPPET, "demo", "--view", f"127.0.0.1:{port}", "--out",
                             str(tmp_path / "v.mp4")], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, process_group=0, cwd=tmp_path)
    try:
        wait_until(lambda: proc.poll() is not None or _encoding(tmp_path / "v.mp4")(),
                   what="the demo under way")
        assert proc.poll() is None, proc.stderr.read()
        proc.kill()
        proc.wait()

        def port_free() -> bool:
            with socket.socket() as again:
                again.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    again.bind(("127.0.0.1", port))
                except OSError:
                    return False
                return True

        wait_until(port_free, what="the page's port free after the kill")
        wait_until(lambda: group_gone(proc.pid), what="every process of the demo ended")
    finally:
        if not group_gone(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
