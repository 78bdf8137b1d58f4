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
comes first; viewers (one shared camera, or their own) share what is left.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np

from puppet.errors import PuppetError
from puppet.events import EVENT_KINDS
from puppet.view.address import Access, bind, parse_address
from puppet.view.encoder import FrameEncoder
from puppet.view.handles import Handle, drag_target, project, surface_bary, surface_point
from puppet.view.orbit import OrbitCamera
from puppet.view.protocol import MAX_HANDLES, PANEL_HZ
from puppet.view.server import KEY_EDITS, ViewServer

log = logging.getLogger("puppet.view")

RING = 64                 # frames remembered for picking (about 1 s at 60 fps)
VIEW_SHARE = 0.6          # the most of the loop's wall time spent rendering for viewers
INTERACTION_S = 0.3       # frames are drafts until this long after the last camera/handle move
KEEPALIVE_S = 2.0         # an idle view (nothing moved, camera still) sends one frame this often
STILL = 1 / 2000          # a pose whose T entries all moved less than this times the model's size
                          # is the same picture (the solver still settling; ~0.2 px at 480 px)
ORBIT_RAD_PER_PX = 0.01
MODES = ("live", "play", "rig")


def bone_legend() -> list[dict]:
    """The overlay's bone colours for the page: [{state, color ('#rrggbb', sRGB), words}]."""
    from puppet.render.overlay import BONE_STATE_COLORS, BONE_STATE_WORDS

    def srgb(c: float) -> int:
        c = 12.92 * c if c <= 0.0031308 else 1.055 * c ** (1 / 2.4) - 0.055
        return round(min(max(c, 0.0), 1.0) * 255)

    return [{"state": state, "color": "#" + "".join(f"{srgb(c):02x}" for c in rgb),
             "words": BONE_STATE_WORDS[state]}
            for state, rgb in BONE_STATE_COLORS.items() if state is not None]


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
    """

    def __init__(self, address: str | None = None, *, mode: str = "live", take_factory=None,
                 takes_dir=".", max_fps: float = 40.0, keys=None):
        if mode not in MODES:
            raise ValueError(f"mode: {mode!r} is not one of {MODES}")
        host, port = parse_address(address)
        self._sock = bind(host, port)
        port = self._sock.getsockname()[1]
        self.access = Access.for_host(host, port)
        self.url = self.access.url()
        self.mode = mode
        self.take_factory = take_factory
        self.takes_dir = Path(takes_dir)
        self.max_fps = float(max_fps)
        self.overlay = True
        self.keys = keys
        self.onion = keys is not None
        self.playhead: int | None = None   # the onion skins' frame; None: where the next key lands
        self.server: ViewServer | None = None
        self.refactor_ms: list[float] = []
        self._commands: deque = deque()
        self._lock = threading.Lock()
        self._closed = False
        self._attached = False

    # ---- setup --------------------------------------------------------------------------------
    def attach(self, pipeline, *, source=None, recorder=None) -> None:
        """Bind the view to a pipeline (with a renderer) and start serving.

        source: the loop's reading source (a TakeSource gets the page's playback controls).
        recorder: the command's own --record writer, so marks go into it too.
        """
        from puppet.render.picking import Picker

        if pipeline.renderer is None:
            raise PuppetError("the live view needs a pipeline with a renderer")
        renderer = pipeline.renderer
        rig = pipeline.rig
        self._pipeline = pipeline
        self._source = source
        self._cli_recorder = recorder
        self.width, self.height = renderer.width, renderer.height
        self.overlay = bool(pipeline.overlay)
        self._start_camera = renderer.camera
        self._cameras: dict[int, OrbitCamera] = {0: OrbitCamera(renderer.camera)}
        self._picker = Picker(renderer)
        self._F = np.asarray(rig.F, np.int64)
        self._servo_ids = [int(i) for i in rig.servo_map.ids]
        self._servo_joints = [s.joint for s in rig.servo_map.servos]
        self._bone_names = list(rig.skeleton.names)
        m = pipeline.model.m
        self._ring_T = np.zeros((RING, 4 * m, 3), np.float32)
        self._T_scratch = np.zeros((4 * m, 3), np.float32)
        V = np.asarray(pipeline.model.V)
        self._still_T = STILL * max(float(np.ptp(V, axis=0).max()), 1e-6)
        self._ring_seq = np.full(RING, -1, np.int64)
        self._ring_camera: list = [None] * RING
        self._last: dict[int, tuple] = {}          # camera -> (T copy, version, overlay, states, draft)
        self._last_render_s: dict[int, float] = {}
        self._seq = 0
        self._handles: list[Handle] = []
        self._next_handle = 1
        self._keys: dict[tuple[str, int], int] = {}  # (client, key) -> handle id
        self._told_background: set = set()
        self._recorder = None
        self._record_path: Path | None = None
        self._markers: list[dict] = []
        self._faults: deque = deque(maxlen=200)
        self._last_fault: dict[int, str] = {}
        self._events_seen = 0
        self._loop_times: deque = deque(maxlen=240)
        self._last_interaction = -1e9
        self._next_panel = 0.0
        self._panel: dict = {"type": "panel"}
        self._camera_panels: dict[int, dict] = {}
        self._last_reading = None
        self._next_render_s = 0.0
        self._t0 = time.monotonic()
        self._angles_deg = np.zeros(len(self._servo_ids))
        self.frames_rendered = 0
        self.frames_reused = 0
        self._onion_version = 0   # counts changes of what the onion skins show
        self._said = None         # the last key command's outcome: (taken, words)
        self._onion = None
        if self.keys is not None:
            from puppet.view.onion import OnionSkins

            self._onion = OnionSkins(rig, self.width, self.height)
        self._ghosts = (-1, None, [])  # (onion version, what they show, [(T, rgb)])
        self._encoder = FrameEncoder(self.width, self.height, self._publish)
        self.server = ViewServer(self._sock, self.access, self)
        self.server.start()
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
            faults = list(self._faults)
            markers = list(self._markers)
            panel = dict(self._panel)
            handles = [h.as_dict() for h in self._handles]
        return {"type": "snapshot", "mode": self.mode, "width": self.width, "height": self.height,
                "servos": [{"id": i, "joint": j} for i, j in zip(self._servo_ids, self._servo_joints)],
                "bones": self._bone_names, "handles": handles, "faults": faults,
                "markers": markers, "overlay": self.overlay, "recording": self._recording_state(),
                "legend": bone_legend(),
                "panel": panel, "playback": self._playback_state(),
                "keys": self._keys_state() if self.keys is not None else None}

    def panel(self, camera: int) -> dict:
        """The newest panel, with the handles and bones as seen by ``camera``."""
        cams = self._camera_panels
        return {**self._panel, **cams.get(camera, cams.get(0, {}))}

    # ---- the loop's side ----------------------------------------------------------------------
    def apply(self, pipeline) -> None:
        """Apply the page input that arrived since the last frame (loop thread, before solving).

        Orbit, pan and zoom are merged into one camera change per camera; drags into one target
        per handle; picks and removals refactor the solver (a pattern switch).
        """
        if not self._commands:
            return
        moves: dict[int, list] = {}
        drags: dict[int, tuple] = {}
        while self._commands:
            client, msg = self._commands.popleft()
            kind = msg["type"]
            try:
                if kind in ("orbit", "pan", "zoom"):
                    move = moves.setdefault(msg["camera"], [0.0, 0.0, 0.0, 0.0, 1.0])
                    if kind == "orbit":
                        move[0] += msg["dx"]
                        move[1] += msg["dy"]
                    elif kind == "pan":
                        move[2] += msg["dx"]
                        move[3] += msg["dy"]
                    else:
                        move[4] *= msg["factor"]
                elif kind == "pick":
                    self._pick(pipeline, client, msg)
                elif kind == "grab":
                    if any(h.id == msg["handle"] for h in self._handles):
                        self._keys[(client, msg["key"])] = msg["handle"]
                elif kind == "drag":
                    handle = self._keys.get((client, msg["key"]))
                    if handle is not None:
                        drags[handle] = (msg["camera"], msg["x"], msg["y"])
                    # else: a drag that started on the background (warned at its pick)
                elif kind == "remove":
                    self._remove(pipeline, msg["handle"])
                elif kind == "preset":
                    self._camera(msg["camera"]).preset(msg["name"])
                    self._touch()
                elif kind == "reset":
                    self._camera(msg["camera"]).reset()
                    self._touch()
                elif kind == "camera_mode":
                    if msg["own"]:
                        self._cameras[msg["camera"]] = self._cameras[0].copy()
                elif kind == "left":
                    if msg["camera"] != 0:
                        self._cameras.pop(msg["camera"], None)
                        if self._onion is not None:
                            self._onion.drop_camera(msg["camera"])
                    self._keys = {k: v for k, v in self._keys.items() if k[0] != client}
                elif kind == "overlay":
                    self.overlay = msg["on"]
                    self.server.send_to(None, {"type": "overlay", "on": self.overlay})
                elif kind == "record":
                    self._record(msg["on"])
                elif kind == "marker":
                    self._mark(msg["name"])
                elif kind == "playback":
                    self._playback(msg["action"], msg["value"])
                elif kind in ("key", "key_edit", "retime", "onion", "playhead"):
                    self._keys_input(client, kind, msg)
            except PuppetError as err:  # told to the page that asked
                self._warn(f"{kind}: {err}", client, kind=f"{kind} refused")
                if kind == "pick":  # the page's pending drag becomes an orbit
                    self.server.send_to(client, {"type": "pick_miss", "key": msg["key"]})
        for camera_id, (dx, dy, px, py, zoom) in moves.items():
            camera = self._camera(camera_id)
            limit = 2.0 * self.width  # pixels per frame: a bogus message cannot throw the camera away
            dx, dy, px, py = (min(max(v, -limit), limit) for v in (dx, dy, px, py))
            zoom = min(max(zoom, 0.05), 20.0)
            if dx or dy:
                camera.orbit(-dx * ORBIT_RAD_PER_PX, dy * ORBIT_RAD_PER_PX)
            if px or py:
                camera.pan(px / self.height, py / self.height)
            if zoom != 1.0:
                camera.zoom(zoom)
            self._touch()
        for handle_id, (camera_id, x, y) in drags.items():
            self._drag(pipeline, handle_id, camera_id, x, y)

    def _touch(self) -> None:
        self._last_interaction = time.monotonic()

    def _camera(self, camera_id: int) -> OrbitCamera:
        camera = self._cameras.get(camera_id)
        if camera is None:
            camera = self._cameras[camera_id] = self._cameras[0].copy()
        return camera

    def _warn(self, text: str, client: str | None = None, kind: str | None = None) -> None:
        """A warning logged and shown on the pages (client: that viewer's only), merged per kind."""
        self.server.warn(text, client, kind)

    # ---- handles ------------------------------------------------------------------------------
    def _pick(self, pipeline, client: str, msg: dict) -> None:
        slot = msg["seq"] % RING
        if self._ring_seq[slot] == msg["seq"]:
            T, camera = self._ring_T[slot], self._ring_camera[slot]
        else:  # the frame is older than the ring: pick on the current pose
            T, camera = pipeline.T, self._camera(msg["camera"]).camera()
        x, y = math.floor(msg["x"]), math.floor(msg["y"])
        start = time.perf_counter()
        hit = self._picker.pick(T, camera, x, y)
        pick_ms = (time.perf_counter() - start) * 1e3
        if hit is None:
            self.server.send_to(client, {"type": "pick_miss", "key": msg["key"]})
            if client not in self._told_background:  # once per viewer: it is also how one orbits
                self._told_background.add(client)
                self._warn(f"a drag that started on the background (at {x}, {y}) moves no handle; "
                           "such drags turn the camera", client)
            return
        triangle = int(hit.triangle)
        bary = surface_bary(hit.bary)
        existing = next((h for h in self._handles if h.triangle == triangle and h.bary == bary), None)
        if existing is not None:
            self._keys[(client, msg["key"])] = existing.id
            self.server.send_to(client, {"type": "handle", "key": msg["key"], "handle": existing.id})
            return
        if len(self._handles) >= MAX_HANDLES:
            raise PuppetError(f"at most {MAX_HANDLES} handles: remove one (right click or double click "
                              "on it) to pin another")
        # The handle starts where its point is now (nothing jumps), then goes where it is dragged.
        point, _ = surface_point(pipeline.model, self._F, pipeline.T, triangle, bary)
        corners = tuple(int(v) for v in self._F[triangle])
        handle = Handle(self._next_handle, triangle, bary, corners, point)
        refactor_ms = self._set_handles(pipeline, self._handles + [handle])
        self._next_handle += 1
        self._keys[(client, msg["key"])] = handle.id
        self.server.send_to(client, {"type": "handle", "key": msg["key"], "handle": handle.id,
                                     "refactor_ms": round(refactor_ms, 3),
                                     "pick_ms": round(pick_ms, 2)})
        self._broadcast_handles()
        self._touch()

    def _set_handles(self, pipeline, handles: list[Handle]) -> float:
        """Refactor for these handles; returns ms. On a PatternError nothing changes."""
        seconds = pipeline.set_handles([h.point for h in handles])
        self._handles = handles
        for i, h in enumerate(handles):
            pipeline.handle_targets[i] = h.target
        ms = seconds * 1e3
        self.refactor_ms.append(ms)
        log.info("view: %d handles, refactor %.2f ms", len(handles), ms)
        return ms

    def _remove(self, pipeline, handle_id: int) -> None:
        kept = [h for h in self._handles if h.id != handle_id]
        if len(kept) == len(self._handles):
            return
        self._set_handles(pipeline, kept)
        self._keys = {k: v for k, v in self._keys.items() if v != handle_id}
        self._broadcast_handles()
        self._touch()

    def _drag(self, pipeline, handle_id: int, camera_id: int, x: float, y: float) -> None:
        index = next((i for i, h in enumerate(self._handles) if h.id == handle_id), None)
        if index is None:
            return
        handle = self._handles[index]
        x = min(max(x, -self.width), 2 * self.width)  # a cursor far off the image moves no further
        y = min(max(y, -self.height), 2 * self.height)
        camera = self._camera(camera_id).camera()
        view_proj = self._picker.view_proj(camera)
        back = camera.basis()[2]
        target = drag_target(view_proj, self.width, self.height, x, y, handle.target, back)
        if target is None or not np.isfinite(target).all():
            return
        handle.target = target
        pipeline.handle_targets[index] = target
        self._touch()

    def _broadcast_handles(self) -> None:
        self.server.send_to(None, {"type": "handles", "handles": [h.as_dict() for h in self._handles]})

    # ---- recording and marks --------------------------------------------------------------------
    def _recording_state(self) -> dict:
        rec = self._recorder
        return {"on": rec is not None, "path": str(self._record_path) if self._record_path else None,
                "readings": rec.writer.count if rec is not None else None}

    def _record(self, on: bool) -> None:
        if on and self._recorder is None:
            if self.take_factory is None:
                raise PuppetError("recording is not available in this mode")
            self.takes_dir.mkdir(parents=True, exist_ok=True)
            stamp = time.strftime("%Y%m%d-%H%M%S")
            path = self.takes_dir / f"take-{stamp}.mcap"
            n = 1
            while path.exists():
                n += 1
                path = self.takes_dir / f"take-{stamp}-{n}.mcap"
            self._recorder = self.take_factory(path)
            self._record_path = path
            log.warning("view: recording %s", path)
        elif not on and self._recorder is not None:
            recorder, self._recorder = self._recorder, None
            recorder.close()
            log.warning("view: recorded %s (%d readings)", self._record_path, recorder.writer.count)
        self.server.send_to(None, {"type": "recording", **self._recording_state()})

    def _mark(self, name: str) -> None:
        reading = self._last_reading
        t_ns = reading.t_ns if reading is not None else time.monotonic_ns()
        stored = []
        for recorder in (self._recorder, self._cli_recorder):
            if recorder is not None:
                recorder.mark(t_ns, name)
                stored.append(str(recorder.path))
        if not stored:
            raise PuppetError(f"marker {name!r} not stored: nothing is recording")
        mark = {"t_s": round((t_ns / 1e9) - self._t0, 3), "name": name, "takes": stored}
        with self._lock:
            self._markers.append(mark)
        self.server.send_to(None, {"type": "marker", **mark})

    # ---- playback -----------------------------------------------------------------------------
    def _playback_state(self) -> dict | None:
        state = getattr(self._source, "state", None)
        return state() if callable(state) else None

    def _playback(self, action: str, value: float) -> None:
        source = self._source
        if not hasattr(source, "seek"):
            raise PuppetError("playback controls need 'puppet play TAKE --view'")
        if action == "pause":
            source.pause()
        elif action == "play":
            source.play()
        elif action == "seek":
            source.seek(value)
        else:
            source.set_speed(value)

    # ---- keys (puppet keys --view) --------------------------------------------------------------
    def _keys_state(self) -> dict:
        """The shot's keys for the page's timeline and its key controls."""
        session = self.keys.session
        keys = session.keys.keys
        next_frame = keys[-1].frame + session.step if keys else 1
        said = self._said
        return {"fps": session.keys.fps, "step": session.step, "next_frame": next_frame,
                "interpolation": session.interpolation,
                "keys": [{"index": k.id, "frame": k.frame, "interpolation": k.interpolation}
                         for k in keys],
                "playhead": self.playhead if self.playhead is not None else next_frame,
                "onion": self.onion, "path": str(session.path),
                "said": said[1] if said else None, "taken": said[0] if said else None}

    def _send_keys(self) -> None:
        self._onion_version += 1
        self.server.send_to(None, {"type": "keys", **self._keys_state()})

    def _keys_input(self, client: str, kind: str, msg: dict) -> None:
        """Page input for the keys: a key (Space, Key button), a key edit (replace, delete,
        insert, interpolation: ``server.KEY_EDITS``) or a retime (a dragged tick) go to the
        KeyDesk as the terminal's command lines; onion skins and their frame stay in the view."""
        if self.keys is None:
            raise PuppetError("keys need 'puppet keys ... --view'")
        if kind == "key":
            self.keys.press("", client)
        elif kind == "key_edit":
            self.keys.press(KEY_EDITS[msg["action"]].format(**msg), client)
        elif kind == "retime":
            self.keys.press(f"t {msg['index']} {msg['frame']}", client)
        elif kind == "onion":
            self.onion = msg["on"]
            self._send_keys()
        else:
            self.playhead = msg["frame"]
            self._send_keys()

    def _keys_frame(self, batch) -> None:
        """The loop's readings to the KeyDesk, and the outcome of the commands it applied told
        to every page (a refusal also as a notice to the page that asked)."""
        desk = self.keys
        desk.feed(batch)
        version = desk.version
        outcomes = desk.step()
        if not outcomes:
            return
        for origin, taken, words in outcomes:
            self._said = (taken, words)
            if not taken and isinstance(origin, str):
                self._warn(words, origin, kind="key refused")
        if desk.version != version and self._onion is not None:
            self._onion.forget(desk.session.keys.keys)
        self._send_keys()

    def _onion_over(self, buffer, camera_id: int, orbit, camera) -> None:
        """Draw the previous and next key's ghosts (around the playhead) over ``buffer``."""
        from puppet.view.onion import NEXT_RGB, PREVIOUS_RGB, neighbours, pose_id

        onion = self._onion
        if self._ghosts[0] != self._onion_version:  # once per change: solved, cached by pose
            state = self._keys_state()
            previous, following = neighbours(self.keys.session.keys.keys, state["playhead"])
            chosen = [(key, rgb) for key, rgb in ((previous, PREVIOUS_RGB), (following, NEXT_RGB))
                      if key is not None]
            self._ghosts = (self._onion_version, tuple((pose_id(k), rgb) for k, rgb in chosen),
                            [(onion.ghost_T(k), rgb) for k, rgb in chosen])
        _, shown, ghosts = self._ghosts
        if not ghosts:
            return
        renderer = self._pipeline.renderer

        def draw(T):
            own = renderer.camera
            if camera is not own:
                renderer.camera = camera
            try:
                renderer.draw(T, out=onion.shade)
            finally:
                if camera is not own:
                    renderer.camera = own
            return onion.shade, self._picker.coverage(T, camera, onion.cover)

        layer = onion.layer(camera_id, (orbit.version, shown), ghosts, draw)
        onion.apply(buffer, layer)

    # ---- per frame ----------------------------------------------------------------------------
    def frame(self, pipeline, batch, image, log_source=None) -> None:
        """After the loop solved the newest reading of ``batch`` (and drew ``image`` for its own
        sinks, or None): record, update the panel, and render a frame for viewers that can take
        one. log_source: the source's EventLog (bus faults), or None."""
        now = time.monotonic()
        self._loop_times.append(now)
        reading = batch[-1]
        self._last_reading = reading
        if self._recorder is not None:
            try:
                for item in batch:
                    self._recorder.write(item)
            except PuppetError as err:
                self._warn(f"recording stopped: {err}")
                self._recorder = None
        if log_source is not None:
            self._take_events(log_source)
        if self.keys is not None:
            self._keys_frame(batch)
        if now >= self._next_panel and self.server.viewers:
            self._next_panel = now + 1.0 / PANEL_HZ
            self._update_panel(pipeline, reading, now)
        server = self.server
        demand = server.demand
        if not demand or self._encoder.busy or now < self._next_render_s:
            return
        camera_id = self._choose_camera(pipeline, demand, now)
        if camera_id is None:
            return
        self._render(pipeline, camera_id, image, reading, now)

    def _choose_camera(self, pipeline, demand, now: float) -> int | None:
        force = self.server.force
        best, best_t = None, math.inf
        period = 1.0 / self.max_fps
        for camera_id in demand:
            last_t = self._last_render_s.get(camera_id, -math.inf)
            if now - last_t < period:
                continue
            if camera_id not in force and now - last_t < KEEPALIVE_S \
                    and not self._dirty(pipeline, camera_id, now):
                continue
            if last_t < best_t:
                best, best_t = camera_id, last_t
        return best

    def _dirty(self, pipeline, camera_id: int, now: float) -> bool:
        last = self._last.get(camera_id)
        if last is None:
            return True
        T, version, overlay, states, draft, onion = last
        camera = self._cameras.get(camera_id)
        if (draft and now - self._last_interaction >= INTERACTION_S) or overlay != self.overlay \
                or onion != self._onion_version \
                or camera is None or version != camera.version or states != pipeline.bone_states:
            return True
        # A still pose: the solver's answer still settles by far less than a pixel per solve.
        scratch = self._T_scratch
        np.subtract(T, pipeline.T, out=scratch)
        np.abs(scratch, out=scratch)
        return bool(scratch.max() > self._still_T)

    def _render(self, pipeline, camera_id: int, image, reading, now: float) -> None:
        orbit = self._camera(camera_id)
        renderer = pipeline.renderer
        buffer = self._encoder.buffer()
        camera = orbit.camera()
        if camera_id == 0 and orbit.pristine and image is not None and self.overlay == pipeline.overlay:
            np.copyto(buffer, image)
            self.frames_reused += 1
        else:
            start = time.monotonic()
            own = renderer.camera
            if camera is not own:
                renderer.camera = camera
            try:
                if self.overlay:
                    renderer.draw(pipeline.T, bones=pipeline.bone_segments,
                                  bone_states=pipeline.bone_states, out=buffer)
                else:
                    renderer.draw(pipeline.T, out=buffer)
            finally:
                if camera is not own:
                    renderer.camera = own
            # The loop's rate comes first: after a render of d seconds for viewers, the next one
            # waits d (1 / VIEW_SHARE - 1) seconds, so viewers get at most that share of its time.
            end = time.monotonic()
            self._next_render_s = end + (end - start) * (1.0 / VIEW_SHARE - 1.0)
            self.frames_rendered += 1
        if self.onion and self._onion is not None:
            self._onion_over(buffer, camera_id, orbit, camera)
        self._seq += 1
        seq = self._seq
        slot = seq % RING
        np.copyto(self._ring_T[slot], pipeline.T)
        self._ring_seq[slot] = seq
        self._ring_camera[slot] = camera
        draft = now - self._last_interaction < INTERACTION_S
        previous = self._last.get(camera_id)
        T_copy = previous[0] if previous is not None else np.empty_like(pipeline.T)
        np.copyto(T_copy, pipeline.T)
        self._last[camera_id] = (T_copy, orbit.version, self.overlay, list(pipeline.bone_states), draft,
                                 self._onion_version)
        self._last_render_s[camera_id] = now
        self.server.force.discard(camera_id)
        self._encoder.submit(buffer, seq, camera_id, int(reading.t_ns), draft)

    # ---- panel and faults -----------------------------------------------------------------------
    def _take_events(self, source_log) -> None:
        total = sum(source_log.counts.values())
        new = total - self._events_seen
        if new <= 0:
            return
        try:
            events = tuple(source_log.events)[-new:] if new <= len(source_log.events) else tuple(source_log.events)
        except RuntimeError:  # appended to while copying: next frame
            return
        self._events_seen = total
        for event in events:
            kind = EVENT_KINDS.get(event.kind)
            fault = kind is None or kind.fault
            item = {"t_s": round(event.t_ns / 1e9 - self._t0, 3), "kind": event.kind,
                    "ids": list(event.ids), "detail": event.detail[:200], "fault": fault,
                    "words": kind.words if kind is not None else event.kind}
            with self._lock:
                self._faults.append(item)
            if fault:  # "last fault" names faults only, in the puppeteer's words
                for servo in event.ids:
                    self._last_fault[int(servo)] = item["words"]
            self.server.send_to(None, {"type": "fault", **item})

    def _update_panel(self, pipeline, reading, now: float) -> None:
        np.degrees(pipeline.angles, out=self._angles_deg)
        times = self._loop_times
        recent = [t for t in times if now - t <= 1.0]
        loop_fps = (len(recent) - 1) / max(recent[-1] - recent[0], 1e-6) if len(recent) > 1 else 0.0
        servos = [{"id": sid, "deg": round(float(deg), 1), "ok": bool(ok),
                   "fault": self._last_fault.get(sid, "")}
                  for sid, deg, ok in zip(self._servo_ids, self._angles_deg, reading.ok)]
        panel = {"type": "panel", "t_s": round(now - self._t0, 2), "servos": servos,
                 "loop_fps": round(loop_fps, 1), "frames": self._seq,
                 "drops": self._encoder.dropped + self.server.drops,
                 "recording": self._recording_state(), "playback": self._playback_state(),
                 "refactor_ms": round(self.refactor_ms[-1], 3) if self.refactor_ms else None}
        cams = {}
        posed = self._posed_bones(pipeline)
        targets = np.array([h.target for h in self._handles]).reshape(-1, 3)
        for camera_id, orbit in list(self._cameras.items()):
            view_proj = self._picker.view_proj(orbit.camera())
            ends = project(view_proj, self.width, self.height, posed.reshape(-1, 3)).reshape(-1, 2, 2)
            spots = project(view_proj, self.width, self.height, targets) if len(targets) else np.zeros((0, 2))
            cams[camera_id] = {
                "bones": [{"name": n, "state": s, "a": [round(float(a), 1) for a in e[0]],
                           "b": [round(float(b), 1) for b in e[1]]}
                          for n, s, e in zip(self._bone_names, pipeline.bone_states, ends)],
                "handles": [{"id": h.id, "x": round(float(p[0]), 1), "y": round(float(p[1]), 1)}
                            for h, p in zip(self._handles, spots)],
            }
        self._camera_panels = cams
        with self._lock:
            self._panel = panel

    def _posed_bones(self, pipeline) -> np.ndarray:
        """(b, 2, 3) bone heads and tails moved by their handles."""
        seg = pipeline.bone_segments
        b = len(seg)
        blocks = pipeline.T.reshape(-1, 4, 3)[:b].astype(np.float64)
        homo = np.concatenate([seg, np.ones((b, 2, 1))], axis=2)
        return np.matmul(homo, blocks)

    # ---- figures and lifetime -----------------------------------------------------------------
    def stats(self) -> dict:
        """Counters for benchmarks and summaries."""
        server = self.server
        latency = sorted(server.latency_ms) if server is not None else []
        return {"frames_sent": self._seq if self._attached else 0,
                "frames_shown": server.shown if server else 0,
                "frames_rendered": self.frames_rendered if self._attached else 0,
                "frames_reused": self.frames_reused if self._attached else 0,
                "encoder_drops": self._encoder.dropped if self._attached else 0,
                "viewer_drops": server.drops if server else 0,
                "bytes_sent": server.bytes_sent if server else 0,
                "latency_ms": latency, "warnings": server.warnings if server else 0,
                "refactor_ms": list(self.refactor_ms)}

    def handles(self) -> list[dict]:
        return [h.as_dict() for h in self._handles] if self._attached else []

    def close(self) -> None:
        """Close a recording from the page (the take is complete), stop serving."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._attached and self._recorder is not None:
                recorder, self._recorder = self._recorder, None
                recorder.close()
                log.warning("view: recorded %s (%d readings)", self._record_path, recorder.writer.count)
        finally:
            if self._attached:
                self._encoder.close()
                if self._onion is not None:
                    self._onion.close()
                self.server.stop()
                if self._pipeline.renderer is not None:  # else its context took the pass's objects
                    self._picker.release()
            self._sock.close()

    def __enter__(self) -> "View":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
