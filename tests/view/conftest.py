"""A real headless Chromium (Debian's, installed by .ci/run) driven by playwright, one browser
per test session; a running ``puppet ... --view`` command as a fixture; waiting helpers.

Every wait polls a condition with a generous timeout (the machine is small and shared): no
fixed sleeps before an assertion, no rate thresholds.
"""

from __future__ import annotations

import asyncio
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

CHROMIUM_ARGS = ["--disable-gpu", "--no-sandbox", "--disable-dev-shm-usage"]
WAIT_S = 90.0
PUPPET = [sys.executable, "-P", "-c", "from puppet.cli import main; main()"]


def chromium_path() -> str:
    """The system chromium binary; the live view's tests need a real browser."""
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        pytest.fail("chromium is not installed: sudo apt-get install -y chromium (.ci/run does it)")
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(condition, timeout: float = WAIT_S, what: str = "condition", interval: float = 0.1):
    """Poll condition() until it returns a truthy value (returned) or fail after timeout."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(interval)


def cli(*args):
    """``puppet ARGS`` run in this process (click's test runner): its Result (``exit_code``,
    ``stderr``); an exception that escaped the command line (a traceback for a user) fails."""
    from click.testing import CliRunner

    from puppet.cli import main

    result = CliRunner().invoke(main, [str(a) for a in args], prog_name="puppet")
    assert isinstance(result.exception, SystemExit), result.exc_info
    return result


class PuppetProcess:
    """A puppet command run with --view in its own folder; ``url`` once it printed it."""

    def __init__(self, args: list[str], cwd: Path, env: dict[str, str] | None = None):
        self.cwd = Path(cwd)
        self.stderr_path = self.cwd / "stderr.txt"
        self.stdout_path = self.cwd / "stdout.txt"
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1", **(env or {}))
        self._err = open(self.stderr_path, "w")
        self._out = open(self.stdout_path, "w")
        self.proc = subprocess.Popen(PUPPET + args, cwd=self.cwd, stdout=self._out, stderr=self._err,
                                     env=env)
        text = wait_until(lambda: self._url_or_exit(), what=f"the URL from puppet {' '.join(args)}")
        if text == "exited":
            pytest.fail(f"puppet {' '.join(args)} exited {self.proc.returncode}: {self.stderr()}")
        self.url = text

    def _url_or_exit(self):
        match = re.search(r"view: (http://\S+)", self.stderr())
        if match:
            return match.group(1)
        return "exited" if self.proc.poll() is not None else None

    def stderr(self) -> str:
        return self.stderr_path.read_text()

    def stdout(self) -> str:
        return self.stdout_path.read_text()

    def stop(self, timeout: float = 60.0) -> int:
        """Ctrl-C, then wait; returns the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._err.close()
        self._out.close()
        return self.proc.returncode


@pytest.fixture(scope="session")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium_path(), headless=True,
                                             args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture
def new_page(browser):
    """Open pages in fresh browser contexts; all closed after the test."""
    contexts = []

    def open_page(url: str | None = None):
        # bypass_csp: the page's policy forbids eval, which playwright's wait_for_function uses.
        context = browser.new_context(viewport={"width": 1200, "height": 800}, bypass_csp=True)
        contexts.append(context)
        page = context.new_page()
        if url is not None:
            page.goto(url)
        return page

    yield open_page
    for context in contexts:
        context.close()


@pytest.fixture
def page(new_page):
    return new_page()


def wait_js(page, expression: str, timeout: float = WAIT_S):
    """Wait until a JavaScript expression on the page is truthy; returns that truthy value (the
    one the wait saw: evaluating again could see a later state, e.g. a panel update)."""
    handle = page.wait_for_function(expression, timeout=timeout * 1000, polling=100)
    try:
        return handle.json_value()
    finally:
        handle.dispose()


@pytest.fixture(scope="session")
def tools():
    """This module's helpers (a conftest is not importable by name)."""
    return sys.modules[__name__]


DROPPED_SERVO = 5


@pytest.fixture(scope="module")
def demo(tmp_path_factory, request):
    """``puppet demo --view`` for a test module; hw_sim drops servo 5 for good 3 s into the run.
    A module's ``DEMO_ENV`` ({name: value}) is added to the command's environment."""
    folder = tmp_path_factory.mktemp("demo_view")
    (folder / "faults.txt").write_text(f"3.0 drop ids={DROPPED_SERVO} for=900\n")
    process = PuppetProcess(["demo", "--view", str(free_port()), "--out", "demo.mp4",
                             "--faults", "faults.txt"], folder,
                            env=getattr(request.module, "DEMO_ENV", None))
    yield process
    status = process.stop()
    assert status == 0, process.stderr()
    assert "Traceback" not in process.stderr()
    assert "frames" in process.stdout()  # the summary: the loop ended cleanly on Ctrl-C
    assert (folder / "demo.mp4").stat().st_size > 0  # --view works together with --out


def wait_still(page, ready: str = "true", timeout: float = WAIT_S) -> int:
    """Wait until the picture is still after the page's JavaScript ``ready`` became true: a frame
    rendered after a panel on which ``ready`` held, then a panel period with no frame rendered
    (the loop renders a picture that changes; a still one only every KEEPALIVE_S), and the page
    showing that frame; returns its seq. A panel carries the count of frames rendered before it."""
    first, seen = [], {}

    def still():
        panels, frames, shown, is_ready = page.evaluate(
            f"[puppetView.panels, puppetView.panel && puppetView.panel.frames, puppetView.shownSeq, "
            f"!!(puppetView.panel && ({ready}))]")
        if not is_ready:
            return None
        first.append(frames)
        seen.setdefault(frames, panels)
        return frames > first[0] and seen[frames] < panels and shown >= frames and frames
    return wait_until(still, timeout, what=f"a still picture after {ready}", interval=0.05)


def frame_image(page):
    """The frame canvas as shown: (h, w, 3) uint8."""
    import io

    import numpy as np
    from PIL import Image

    png = page.locator("#frame").screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def open_view(new_page, target, frames: int = 1):
    """A page on a running view (a PuppetProcess or a URL), once it has shown ``frames`` frames
    (a still picture gets a new frame only every KEEPALIVE_S: wait for more only when moving)."""
    page = new_page(target if isinstance(target, str) else target.url)
    wait_js(page, f"window.puppetView && puppetView.shown >= {frames}")
    return page


def open_studio(new_page, process, width: int = 1280, height: int = 800, timeout: float = 120.0):
    """A page on a running ``puppet studio`` (a PuppetProcess), once it shows the studio and a
    frame; a page that never does says what it saw and the studio's stderr."""
    page = new_page()
    page.set_viewport_size({"width": width, "height": height})
    page.goto(process.url)
    try:
        wait_js(page, "puppetView.studio !== null && puppetView.shownSeq >= 0", timeout)
    except Exception as err:  # what the page and the studio were doing, for the report
        seen = page.evaluate("({studio: puppetView.studio !== null, shown: puppetView.shownSeq, "
                             "connected: puppetView.connected})")
        raise AssertionError(f"{err}\npage: {seen}\nstudio stderr:\n{process.stderr()[-3000:]}"
                             ) from None
    return page


def is_character(block) -> bool:
    """Any pixel of the (warm, orange) character in a block (h, w, 3) of a frame."""
    rgb = block.reshape(-1, 3).astype(int)
    return bool(((rgb[:, 0] - rgb[:, 2]) > 45).any())


def side_panel(page, before):
    """The page's panel once the tail's bone moved over 5 px from ``before`` (x, y) on it (the
    camera turned), else None."""
    import numpy as np

    panel = page.evaluate("({frames: puppetView.panel.frames, "
                          "tail: puppetView.bones.find(b => b.name === 'tail3').b})")
    return panel if np.hypot(*np.subtract(panel["tail"], before)) > 5 else None


def drag_tail(page):
    """Turn the shared camera to the side, press on the tail and drag it onto the background.
    Returns the target (x, y) image position; fails if the press missed the surface."""
    import numpy as np

    wait_js(page, "puppetView.bones.length > 0")
    before, drafts = page.evaluate("[puppetView.bones.find(b => b.name === 'tail3').b, puppetView.drafts]")
    page.click("button[data-preset='side']")
    side = wait_until(lambda: side_panel(page, before), what="the side view")
    # A sharp frame of the side view: rendered after that panel (a panel carries the frames
    # rendered before it) and after a draft (frames are drafts while the camera turns), or, when
    # no draft was shown, four frames after it (as many as can be on the way); then the bones
    # of a panel built after that frame.
    shown = wait_js(page, f"!puppetView.draft && puppetView.shownSeq > {side['frames']} && "
                          f"(puppetView.drafts > {drafts} || puppetView.shownSeq > {side['frames']} + 3) "
                          f"&& puppetView.shownSeq")
    wait_js(page, f"puppetView.panel.frames >= {shown}")
    tail = page.evaluate("puppetView.bones.find(b => b.name === 'tail3')")
    grab = (np.array(tail["a"]) + 2 * np.array(tail["b"])) / 3
    image = frame_image(page)
    width, height = image.shape[1], image.shape[0]
    targets = [grab + d for d in ((0, -90), (-90, 0), (90, 0), (0, 90), (-70, -70), (70, -70))]
    targets = [t for t in targets if 8 <= t[0] < width - 8 and 8 <= t[1] < height - 8
               and not is_character(image[int(t[1]) - 4:int(t[1]) + 5, int(t[0]) - 4:int(t[0]) + 5])]
    assert targets, "no background next to the tail to drag it to"
    target = targets[0]
    box = page.locator("#marks").bounding_box()
    scale = box["width"] / width
    page.mouse.move(box["x"] + grab[0] * scale, box["y"] + grab[1] * scale)
    page.mouse.down()
    page.mouse.move(box["x"] + target[0] * scale, box["y"] + target[1] * scale, steps=12)
    page.mouse.up()
    pick = wait_js(page, "puppetView.lastPick")
    assert pick["handle"] is not None, "the press on the tail did not hit the surface"
    return int(target[0]), int(target[1])


def run_async(coroutine):
    """Run a coroutine to completion on its own thread (playwright's sync API holds an event loop
    on this one)."""
    import concurrent.futures

    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coroutine).result(timeout=WAIT_S)
