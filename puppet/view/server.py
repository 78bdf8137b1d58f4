"""The view's web server (aiohttp on its own thread): the page, the frame and control sockets,
per-viewer credit and latest-wins slots, access checks.

Threads: the server runs an asyncio loop on a daemon thread. The render loop hands it encoded
frames (``publish``, thread-safe) and reads ``demand`` (the camera ids some viewer has credit
for); page input goes to the loop through ``View.command`` (a deque the loop drains).
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from importlib import resources

from aiohttp import WSMsgType, web

from puppet.view.address import Access
from puppet.view.encoder import EncodedFrame
from puppet.view.protocol import CREDIT, FLAG_DRAFT, MAX_CLIENT_MESSAGE, PANEL_HZ, frame_header

log = logging.getLogger("puppet.view")

COOKIE = "puppet_view_token"
STATIC_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css", ".svg": "image/svg+xml"}
PAGE_HEADERS = {
    "Cache-Control": "no-store",
    "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}


def _static_files() -> dict[str, tuple[bytes, str]]:
    """Every file of puppet/view/static, read once: name -> (bytes, content type)."""
    folder = resources.files("puppet.view") / "static"
    out = {}
    for entry in folder.iterdir():
        suffix = "." + entry.name.rsplit(".", 1)[-1]
        if suffix in STATIC_TYPES:
            out[entry.name] = (entry.read_bytes(), STATIC_TYPES[suffix])
    return out


@dataclass(eq=False)
class Viewer:
    """One page (a tab): its two sockets, its camera, its credit and its latest-wins slot."""

    client: str
    number: int
    frames: web.WebSocketResponse | None = None
    control: web.WebSocketResponse | None = None
    camera: int = 0
    credit: int = CREDIT
    slot: EncodedFrame | None = None
    inflight: dict = field(default_factory=dict)   # seq -> reading t_ns
    sent: int = 0
    shown: int = 0
    drops: int = 0
    bytes_sent: int = 0
    shown_times: deque = field(default_factory=lambda: deque(maxlen=120))

    def fps(self, now: float) -> float:
        times = [t for t in self.shown_times if now - t <= 2.0]
        if len(times) < 2:
            return 0.0
        return (len(times) - 1) / max(times[-1] - times[0], 1e-6)


class ViewServer:
    """Serves the page and its sockets on an already bound socket.

    sock: listening socket (bound by the caller, so a taken port fails before anything starts).
    access: the address and token rules. view: the View (snapshot(), panel(viewer), command()).
    """

    def __init__(self, sock, access: Access, view):
        self._sock = sock
        self.access = access
        self.view = view
        self.viewers: dict[str, Viewer] = {}
        self.demand: frozenset = frozenset()   # camera ids some viewer can take a frame for
        self.force: set = set()                # camera ids that need a frame now (a viewer joined)
        self.latency_ms: deque = deque(maxlen=4000)
        self.shown = 0
        self.drops = 0
        self.bytes_sent = 0
        self.warnings = 0
        self._numbers = 0
        self._static = _static_files()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._runner: web.AppRunner | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="view-server", daemon=True)

    # ---- lifetime -----------------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            raise self._error

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except OSError as err:  # reported to start()
            self._error = err
            self._ready.set()
            return
        self._ready.set()
        panel = loop.create_task(self._panel_task())
        try:
            loop.run_forever()
        finally:
            panel.cancel()
            loop.run_until_complete(self._shutdown())
            loop.close()

    async def _serve(self) -> None:
        app = web.Application(middlewares=[self._guard], client_max_size=MAX_CLIENT_MESSAGE)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._file)
        app.router.add_get("/favicon.ico", self._no_icon)
        app.router.add_get("/ws/frames", self._frames_socket)
        app.router.add_get("/ws/control", self._control_socket)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=1.0)
        await self._runner.setup()
        await web.SockSite(self._runner, self._sock).start()

    async def _shutdown(self) -> None:
        for viewer in list(self.viewers.values()):
            for ws in (viewer.frames, viewer.control):
                if ws is not None and not ws.closed:
                    await ws.close()
        if self._runner is not None:
            await self._runner.cleanup()

    def stop(self) -> None:
        if self._loop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=10)

    # ---- access -------------------------------------------------------------------------------
    @web.middleware
    async def _guard(self, request: web.Request, handler):
        if not self.access.host_ok(request.headers.get("Host")):
            self.warn(f"refused {request.path}: Host {request.headers.get('Host')!r} is not loopback")
            return web.Response(status=403, text="forbidden: wrong Host\n")
        query_token = request.query.get("token")
        token = query_token if query_token is not None else request.cookies.get(COOKIE)
        if not self.access.token_ok(token):
            self.warn(f"refused {request.path} from {request.remote}: missing or wrong token")
            return web.Response(status=403, text="forbidden: open the URL puppet printed (with its token)\n")
        if request.path.startswith("/ws/"):
            origin = request.headers.get("Origin")
            if origin != f"http://{request.host}":
                self.warn(f"refused a WebSocket from origin {origin!r} (page at http://{request.host})")
                return web.Response(status=403, text="forbidden: cross-origin WebSocket\n")
        response = await handler(request)
        if self.access.token is not None and query_token is not None and request.path == "/":
            response.set_cookie(COOKIE, query_token, httponly=True, samesite="Strict")
        return response

    def warn(self, text: str) -> None:
        """Log a warning (stderr) and show it on the pages."""
        self.warnings += 1
        log.warning("view: %s", text)
        self._broadcast_now({"type": "notice", "level": "warning", "text": text})

    # ---- page and files -------------------------------------------------------------------------
    async def _index(self, request: web.Request) -> web.Response:
        body, kind = self._static["index.html"]
        return web.Response(body=body, content_type=kind, headers=PAGE_HEADERS)

    async def _no_icon(self, request: web.Request) -> web.Response:
        return web.Response(status=204)

    async def _file(self, request: web.Request) -> web.Response:
        item = self._static.get(request.match_info["name"])
        if item is None:
            return web.Response(status=404, text="not found\n")
        return web.Response(body=item[0], content_type=item[1], headers=PAGE_HEADERS)

    # ---- viewers ------------------------------------------------------------------------------
    def _viewer(self, request: web.Request) -> Viewer | None:
        client = request.query.get("client", "")
        if not (0 < len(client) <= 64 and client.isalnum()):
            return None
        viewer = self.viewers.get(client)
        if viewer is None:
            self._numbers += 1
            viewer = self.viewers[client] = Viewer(client, self._numbers)
        return viewer

    def _forget(self, viewer: Viewer) -> None:
        if viewer.frames is None and viewer.control is None:
            self.viewers.pop(viewer.client, None)
            self.view.command(viewer.client, {"type": "left", "camera": viewer.camera})
        self._update_demand()

    def _update_demand(self) -> None:
        self.demand = frozenset(v.camera for v in self.viewers.values()
                                if v.frames is not None and v.credit > 0)

    async def _accept(self, request: web.Request) -> tuple[Viewer | None, web.StreamResponse]:
        """The requesting viewer and its WebSocket, prepared (upgraded); (None, a 400 response)
        when the request names no valid client id."""
        viewer = self._viewer(request)
        if viewer is None:
            return None, web.Response(status=400, text="missing client id\n")
        ws = web.WebSocketResponse(max_msg_size=MAX_CLIENT_MESSAGE, compress=False)
        await ws.prepare(request)
        return viewer, ws

    async def _receive(self, viewer: Viewer, ws: web.WebSocketResponse, socket: str,
                       on_text) -> None:
        """Hand each text message of ws to on_text(viewer, text) until the socket closes.

        socket: its name in warnings ("frame", "control"); a binary message is ignored and a
        socket error reported, each with a warning naming the viewer.
        """
        async for msg in ws:
            if msg.type == WSMsgType.TEXT:
                on_text(viewer, msg.data)
            elif msg.type == WSMsgType.BINARY:
                self.warn(f"viewer {viewer.number}: unexpected binary message on the {socket} socket ignored")
            elif msg.type == WSMsgType.ERROR:
                self.warn(f"viewer {viewer.number}: {socket} socket closed: {ws.exception()}")

    async def _frames_socket(self, request: web.Request) -> web.StreamResponse:
        viewer, ws = await self._accept(request)
        if viewer is None:
            return ws  # 400: no client id
        if viewer.frames is not None and not viewer.frames.closed:
            await viewer.frames.close()
        viewer.frames, viewer.credit, viewer.slot = ws, CREDIT, None
        viewer.inflight.clear()
        self.force.add(viewer.camera)
        self._update_demand()
        try:
            await self._receive(viewer, ws, "frame", self._frames_message)
        finally:
            if viewer.frames is ws:
                viewer.frames = None
                viewer.slot = None
                self._forget(viewer)
        return ws

    def _frames_message(self, viewer: Viewer, text: str) -> None:
        message = _parse(text)
        if message is None or message.get("type") != "ack" or not isinstance(message.get("seq"), int):
            self.warn(f"viewer {viewer.number}: malformed message on the frame socket ignored: {text[:60]!r}")
            return
        reading_t_ns = viewer.inflight.pop(message["seq"], None)
        if reading_t_ns is None:
            return
        now = time.monotonic_ns()
        self.latency_ms.append((now - reading_t_ns) / 1e6)
        viewer.shown += 1
        self.shown += 1
        viewer.shown_times.append(now / 1e9)
        viewer.credit = min(CREDIT, viewer.credit + 1)
        if viewer.slot is not None:
            frame, viewer.slot = viewer.slot, None
            self._send(viewer, frame)
        self._update_demand()

    async def _control_socket(self, request: web.Request) -> web.StreamResponse:
        viewer, ws = await self._accept(request)
        if viewer is None:
            return ws  # 400: no client id
        viewer.control = ws
        snapshot = self.view.snapshot()
        snapshot["viewer"] = viewer.number
        await ws.send_str(json.dumps(snapshot))
        try:
            await self._receive(viewer, ws, "control", self._control_message)
        finally:
            if viewer.control is ws:
                viewer.control = None
                self._forget(viewer)
        return ws

    def _control_message(self, viewer: Viewer, text: str) -> None:
        message = _parse(text)
        problem = check_input(message)
        if problem is not None:
            self.warn(f"viewer {viewer.number}: {problem}; ignored: {text[:60]!r}")
            return
        if message["type"] == "camera_mode":
            viewer.camera = viewer.number if message["own"] else 0
            message = {**message, "camera": viewer.camera}
            self.force.add(viewer.camera)
            viewer.slot = None
            self._update_demand()
        else:
            message = {**message, "camera": viewer.camera}
        self.view.command(viewer.client, message)

    # ---- frames -------------------------------------------------------------------------------
    def publish(self, frame: EncodedFrame) -> None:
        """Deliver an encoded frame to the viewers of its camera (any thread)."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._deliver, frame)

    def _deliver(self, frame: EncodedFrame) -> None:
        for viewer in self.viewers.values():
            if viewer.frames is None or viewer.camera != frame.camera:
                continue
            if viewer.credit > 0:
                self._send(viewer, frame)
            else:
                if viewer.slot is not None:
                    viewer.drops += 1
                    self.drops += 1
                viewer.slot = frame
        self._update_demand()

    def _send(self, viewer: Viewer, frame: EncodedFrame) -> None:
        ws = viewer.frames
        if ws is None or ws.closed:
            return
        viewer.credit -= 1
        viewer.inflight[frame.seq] = frame.reading_t_ns
        if len(viewer.inflight) > 4 * CREDIT:  # acks lost: forget the oldest
            for seq in sorted(viewer.inflight)[: len(viewer.inflight) - 4 * CREDIT]:
                del viewer.inflight[seq]
        data = frame_header(FLAG_DRAFT if frame.draft else 0, frame.camera, frame.seq,
                            frame.reading_t_ns, time.monotonic_ns()) + frame.jpeg
        viewer.sent += 1
        viewer.bytes_sent += len(data)
        self.bytes_sent += len(data)
        asyncio.ensure_future(self._write(viewer, ws, data))

    async def _write(self, viewer: Viewer, ws, data: bytes) -> None:
        try:
            await ws.send_bytes(data)
        except (ConnectionError, RuntimeError) as err:
            self.warn(f"viewer {viewer.number} went away mid-stream ({type(err).__name__})")

    # ---- panel --------------------------------------------------------------------------------
    async def _panel_task(self) -> None:
        period = 1.0 / PANEL_HZ
        while True:
            await asyncio.sleep(period)
            now = time.monotonic()
            for viewer in list(self.viewers.values()):
                ws = viewer.control
                if ws is None or ws.closed:
                    continue
                panel = self.view.panel(viewer.camera)
                panel["viewer"] = {"number": viewer.number, "fps": round(viewer.fps(now), 1),
                                   "drops": viewer.drops, "shown": viewer.shown,
                                   "camera": viewer.camera}
                panel["latency_ms"] = self.latency_summary()
                try:
                    await ws.send_str(json.dumps(panel))
                except (ConnectionError, RuntimeError):
                    pass  # the control socket's own handler notices the close and forgets it

    def latency_summary(self) -> dict:
        recent = list(self.latency_ms)[-300:]
        if not recent:
            return {"median": None, "p99": None}
        recent.sort()
        return {"median": round(recent[len(recent) // 2], 1),
                "p99": round(recent[min(len(recent) - 1, math.ceil(0.99 * len(recent)) - 1)], 1)}

    def send_to(self, client: str | None, message: dict) -> None:
        """Send a control message to one viewer (None: every viewer); any thread."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._send_control, client, json.dumps(message))

    def _broadcast_now(self, message: dict) -> None:
        if self._loop is not None and threading.current_thread() is self._thread:
            self._send_control(None, json.dumps(message))
        else:
            self.send_to(None, message)

    def _send_control(self, client: str | None, text: str) -> None:
        for viewer in self.viewers.values():
            if (client is None or viewer.client == client) and viewer.control is not None \
                    and not viewer.control.closed:
                asyncio.ensure_future(self._write_control(viewer.control, text))

    async def _write_control(self, ws, text: str) -> None:
        try:
            await ws.send_str(text)
        except (ConnectionError, RuntimeError):
            pass  # the socket's handler forgets the viewer


def _parse(text: str):
    try:
        message = json.loads(text)
    except ValueError:
        return None
    return message if isinstance(message, dict) else None


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


#: Page input: message type -> {field: check}.
INPUTS = {
    "pick": {"key": lambda v: isinstance(v, int), "seq": lambda v: isinstance(v, int),
             "x": _number, "y": _number},
    "grab": {"key": lambda v: isinstance(v, int), "handle": lambda v: isinstance(v, int)},
    "drag": {"key": lambda v: isinstance(v, int), "x": _number, "y": _number},
    "remove": {"handle": lambda v: isinstance(v, int)},
    "orbit": {"dx": _number, "dy": _number},
    "pan": {"dx": _number, "dy": _number},
    "zoom": {"factor": lambda v: _number(v) and 0.05 <= v <= 20},
    "preset": {"name": lambda v: v in ("front", "side", "back", "top")},
    "reset": {},
    "camera_mode": {"own": lambda v: isinstance(v, bool)},
    "overlay": {"on": lambda v: isinstance(v, bool)},
    "record": {"on": lambda v: isinstance(v, bool)},
    "marker": {"name": lambda v: isinstance(v, str) and 0 < len(v) <= 80},
    "playback": {"action": lambda v: v in ("pause", "play", "seek", "speed"), "value": _number},
}


def check_input(message) -> str | None:
    """None when message is a well-formed page input, else what is wrong with it."""
    if message is None:
        return "not a JSON object"
    kind = message.get("type")
    fields = INPUTS.get(kind)
    if fields is None:
        return f"unknown message type {kind!r}"
    for name, ok in fields.items():
        if name not in message or not ok(message[name]):
            return f"{kind}: field {name!r} missing or invalid"
    return None
