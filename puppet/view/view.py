"""View: the live view as the loop sees it: ``apply(pipeline)`` before each solve, ``frame(...)``
after it.

    view = View("127.0.0.1:8765")           # binds now: a taken port fails before any hardware
    view.attach(pipeline, source=source)    # starts the server; view.url is the page
    run_live(pipeline, source, view=view)   # the loop calls apply() and frame() every frame
    view.close()

Threads: the loop (GL, solver, handles, cameras, recording), the server (sockets, credit,
slots), the encoder (JPEG). The loop renders for the view only when some viewer has credit for
a frame, the encoder is free and the picture changed (an idle view: one keep-alive frame every
KEEPALIVE_S), at most ``max_fps`` per camera and one view render per loop frame; the shared camera, untouched, reuses the frame the loop already drew
for its video (no render at all). Renders for viewers take at most VIEW_SHARE of the loop's wall
time (after a render of d seconds the next waits d (1 / VIEW_SHARE - 1) seconds): the loop's rate
comes first; viewers (one shared camera, or their own) share what is left (puppet.view.frames).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from pathlib import Path

from puppet.errors import PuppetError
from puppet.net.address import Access, bind, parse_address
from puppet.view.cameras import Cameras
from puppet.view.frames import ViewFrames
from puppet.view.handle_desk import HandleDesk
from puppet.view.input import PageInput
from puppet.view.key_poses import KeyPoses
from puppet.view.onion import GHOST_LEGEND
from puppet.view.panel import Panel, bone_legend
from puppet.view.playback import Playback
from puppet.view.recording import Recording
from puppet.view.protocol import DEFAULT_PORT
from puppet.view.server import ViewServer

MODES = ("live", "play", "rig")


class View:
    """The live view of one loop.

    address:      '[HOST:]PORT' ('' or None: 127.0.0.1 and the default port); bound at once.
    mode:         'live' (a bus), 'play' (a take: pause, seek, speed) or 'rig' (no bus).
    take_factory: path -> an open BackgroundTakeWriter for the page's record button (None: the
                  button is refused).
    takes_dir:    folder for takes recorded from the page.
    max_fps:      most frames per second sent per camera.
    keys:         a ``puppet.keys.capture.KeyDesk`` (``puppet keys --view``): the page's Space,
                  Key button and timeline go to it, and the page shows the shot's keys as ticks
                  and the previous and next key as onion skins; None: no keys.

    The view is a facade over its parts, made by ``attach``: ``cameras`` (Cameras), ``frames``
    (ViewFrames: what is rendered for whom, the encoder), ``handle_desk`` (HandleDesk: picks and
    drags), ``recording`` (Recording: the record button and marks), ``playback`` (Playback),
    ``key_poses`` (KeyPoses: keys and onion skins), the panel (Panel) and the page input
    (PageInput, which routes each message to its part).

    studio:       a ``puppet.view.studio_desk.StudioDesk`` (``puppet studio``): the session's
                  shots and takes on the page; the record button records its takes (count-in)
                  and the source is the studio's switchable one (review); None: no studio.
    """

    def __init__(self, address: str | None = None, *, mode: str = "live", take_factory=None,
                 takes_dir=".", max_fps: float = 40.0, keys=None, studio=None):
        if mode not in MODES:
            raise ValueError(f"mode: {mode!r} is not one of {MODES}")
        host, port = parse_address(address, option="--view", default_port=DEFAULT_PORT)
        self._sock = bind(host, port, option="--view")
        port = self._sock.getsockname()[1]
        self.access = Access.for_host(host, port)
        self.url = self.access.url()
        self.mode = mode
        self.take_factory = take_factory
        self.takes_dir = Path(takes_dir)
        self.max_fps = float(max_fps)
        self.keys = keys
        self.studio = studio
        self.key_poses = KeyPoses(keys, ghosts=studio is not None)
        self.server: ViewServer | None = None
        self.refactor_ms: list[float] = []
        self._commands: deque = deque()
        self._lock = threading.Lock()
        self._closed = False
        self._attached = False

    def attach(self, pipeline, *, source=None, recorder=None) -> None:
        """Bind the view to a pipeline (with a renderer) and start serving.

        source: the loop's reading source (a TakeSource gets the page's playback controls).
        recorder: the command's own --record writer, so marks go into it too.
        """
        from puppet.render.passes.picking import Picker

        if pipeline.renderer is None:
            raise PuppetError("the live view needs a pipeline with a renderer")
        renderer = pipeline.renderer
        rig = pipeline.rig
        self._pipeline = pipeline
        self.width, self.height = width, height = renderer.width, renderer.height
        self._servo_ids = [int(i) for i in rig.servo_map.ids]
        self._servo_joints = [s.joint for s in rig.servo_map.servos]
        self._bone_names = list(rig.skeleton.names)
        t0 = time.monotonic()
        server = self.server = ViewServer(self._sock, self.access, self)  # serves once started, below
        self._picker = Picker(renderer)
        self.cameras = Cameras(renderer.camera, width, height)
        self.key_poses.attach(rig, width, height, renderer, self._picker, server)
        self.frames = ViewFrames(pipeline, self.cameras, self.key_poses, server, width=width, height=height,
                                 overlay=bool(pipeline.overlay), max_fps=self.max_fps, publish=self._publish)
        self.handle_desk = HandleDesk(rig.F, self._picker, self.cameras, server, self.frames.seen,
                                      self.refactor_ms)
        self.recording = Recording(self.take_factory, self.takes_dir, recorder, server, self._lock, t0,
                                   slate=self.studio)
        if self.studio is not None:
            self.studio.attach(server, source, self.recording, self.key_poses)
        self.playback = Playback(source)
        self._panel = Panel(self._servo_ids, self._bone_names, width, height, self._picker.view_proj,
                            server, self._lock, t0)
        self._input = PageInput(self._commands, cameras=self.cameras, handle_desk=self.handle_desk,
                                recording=self.recording, playback=self.playback, key_poses=self.key_poses,
                                frames=self.frames, server=server, studio=self.studio)
        server.start()
        self._attached = True

    def _publish(self, frame) -> None:
        self.server.publish(frame)

    # ---- server-side hooks (server thread) ----------------------------------------------------
    def command(self, client: str, message: dict) -> None:
        """Queue one checked page input for the loop."""
        self._commands.append((client, message))

    def snapshot(self) -> dict:
        """Everything a viewer that joins late needs before the updates."""
        with self._lock:
            faults = list(self._panel.faults)
            markers = list(self.recording.markers)
            panel = dict(self._panel.latest)
            handles = self.handle_desk.as_dicts()
        return {"type": "snapshot", "mode": self.mode, "width": self.width, "height": self.height,
                "servos": [{"id": i, "joint": j} for i, j in zip(self._servo_ids, self._servo_joints)],
                "bones": self._bone_names, "handles": handles, "faults": faults,
                "markers": markers, "overlay": self.frames.overlay, "recording": self.recording.state(),
                "legend": bone_legend(), "ghost_legend": GHOST_LEGEND,
                "panel": panel, "playback": self.playback.state(),
                "keys": self.key_poses.state(),
                "studio": self.studio.state() if self.studio is not None else None}

    def panel(self, camera: int) -> dict:
        """The newest panel, with the handles and bones as seen by ``camera``."""
        return self._panel.for_camera(camera)

    # ---- the loop's side ----------------------------------------------------------------------
    def apply(self, pipeline) -> None:
        """Apply the page input that arrived since the last frame (loop thread, before solving):
        see PageInput.apply."""
        if self._commands:
            self._input.apply(pipeline)

    def frame(self, pipeline, batch, image, log_source=None) -> None:
        """After the loop solved the newest reading of ``batch`` (and drew ``image`` for its own
        sinks, or None): record, update the panel, and render a frame for viewers that can take
        one. log_source: the source's EventLog (bus faults), or None."""
        now = time.monotonic()
        self._panel.tick(now)
        reading = batch[-1]
        self.recording.write(batch)
        if log_source is not None:
            self._panel.take_events(log_source)
        self.key_poses.feed(batch)
        if self.studio is not None:
            self.studio.follow()
            self.studio.refresh(now)
        if self._panel.due(now):
            self._panel.update(pipeline, reading, now, frames=self.frames.seq,
                               drops=self.frames.encoder.dropped + self.server.drops,
                               recording=self.recording.state(), playback=self.playback.state(),
                               refactor_ms=self.refactor_ms, handles=self.handle_desk.handles,
                               cameras=self.cameras.orbits)
        self.frames.offer(pipeline, image, reading, now)

    # ---- figures and lifetime -----------------------------------------------------------------
    def stats(self) -> dict:
        """Counters for benchmarks and summaries."""
        server = self.server
        attached = self._attached
        latency = sorted(server.latency_ms) if server is not None else []
        return {"frames_sent": self.frames.seq if attached else 0,
                "frames_shown": server.shown if server else 0,
                "frames_rendered": self.frames.rendered if attached else 0,
                "frames_reused": self.frames.reused if attached else 0,
                "encoder_drops": self.frames.encoder.dropped if attached else 0,
                "viewer_drops": server.drops if server else 0,
                "bytes_sent": server.bytes_sent if server else 0,
                "latency_ms": latency, "warnings": server.warnings if server else 0,
                "refactor_ms": list(self.refactor_ms)}

    def handles(self) -> list[dict]:
        return self.handle_desk.as_dicts() if self._attached else []

    def close(self) -> None:
        """Close a recording from the page (the take is complete), stop serving."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._attached:
                self.recording.close()
            if self.studio is not None:
                self.studio.close()
        finally:
            if self._attached:
                self.frames.close()
                self.key_poses.close()
                self.server.stop()
                if self._pipeline.renderer is not None:  # else its context took the pass's objects
                    self._picker.release()
            self._sock.close()

    def __enter__(self) -> "View":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
