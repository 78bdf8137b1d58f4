"""The view's web server (aiohttp on its own thread): the page, the frame and control sockets,
per-viewer credit and latest-wins slots, access checks, flood limits.

No viewer can stall another: each one has its own send path (frames: credit and a latest-wins
slot; control: an ``Outbox`` with a latest-wins panel and a bounded message list, drained by that
viewer's own writer task); nothing on the server's loop awaits a viewer's socket. A viewer whose
socket takes no data for STALL_DROP_S seconds (``$PUPPET_VIEW_STALL_DROP_S`` sets another) is
dropped with a note. Page input passes per
connection rate limits before it is parsed; notices about a viewer's bad input go to that viewer
only, merged per kind; refused requests are only logged (rate-limited).

Threads: the server runs an asyncio loop on a daemon thread. The render loop hands it encoded
frames (``publish``, thread-safe) and reads ``demand`` (the camera ids some viewer has credit
for); page input goes to the loop through ``View.command`` (a deque the loop drains).
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from importlib import resources

from aiohttp import WSMsgType, web

from puppet.take.keys import INTERPOLATIONS, MAX_FRAME
from puppet.net.address import Access
from puppet.view.encoder import EncodedFrame
from puppet.net.guard import RateLimit, Throttle, parse_message
from puppet.view.protocol import (CREDIT, EDIT_BURST, EDIT_RATE_HZ, FLAG_DRAFT, INPUT_BURST, INPUT_RATE_HZ,
                                  MAX_CLIENT_MESSAGE, CONTROL_SNDBUF, NOTICE_EVERY_S, OUTBOX_MESSAGES,
                                  PANEL_HZ, PICK_BURST, PICK_RATE_HZ,
                                  frame_header, stall_drop_s)

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


class Outbox:
    """One viewer's control messages waiting to be sent: the newest panel (latest wins) and at
    most OUTBOX_MESSAGES others, in order (the oldest dropped first, counted in ``lost``).
    ``busy_since``: when the send in progress began (monotonic s), None when none waits."""

    def __init__(self):
        self.panel: str | None = None
        self.messages: deque = deque(maxlen=OUTBOX_MESSAGES)
        self.lost = 0
        self.busy_since: float | None = None
        self.ready = asyncio.Event()

    def put(self, text: str) -> None:
        if len(self.messages) == self.messages.maxlen:
            self.lost += 1
        self.messages.append(text)
        self.ready.set()

    def put_panel(self, text: str) -> None:
        self.panel = text
        self.ready.set()

    def take(self) -> str | None:
        if self.messages:
            return self.messages.popleft()
        text, self.panel = self.panel, None
        return text


@dataclass(eq=False)
class Viewer:
    """One page (a tab): its two sockets, its camera, its credit and its latest-wins slot, its
    control outbox, its notices and counters of input refused."""

    client: str
    number: int
    frames: web.WebSocketResponse | None = None
    control: web.WebSocketResponse | None = None
    transports: dict = field(default_factory=dict)   # ws -> its transport (to drop a stuck one)
    outbox: Outbox | None = None
    frame_writes: dict = field(default_factory=dict)  # seq -> when its send began (monotonic s)
    notices: Throttle = field(default_factory=lambda: Throttle(NOTICE_EVERY_S))
    picks: RateLimit = field(default_factory=lambda: RateLimit(PICK_RATE_HZ, PICK_BURST))
    edits: RateLimit = field(default_factory=lambda: RateLimit(EDIT_RATE_HZ, EDIT_BURST))
    ignored: int = 0        # malformed messages and messages of kinds the page never sends
    limited: int = 0        # messages over the rate limits (dropped unread)
    camera: int = 0
    credit: int = CREDIT
    slot: EncodedFrame | None = None
    inflight: dict = field(default_factory=dict)   # seq -> (reading t_ns, send t_ns)
    latency_ms: deque = field(default_factory=lambda: deque(maxlen=300))  # this tab's reading -> drawn
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
        #: (reading -> send, send -> arrival and the ack back, arrival -> drawn) ms per shown frame
        self.latency_split: deque = deque(maxlen=4000)
        self.shown = 0
        self.drops = 0
        self.bytes_sent = 0
        self.warnings = 0
        self.refused = 0
        self.dropped_viewers = 0
        self.stall_drop_s = stall_drop_s()  # protocol.STALL_DROP_S unless the environment says
        self._notices = Throttle(NOTICE_EVERY_S)   # notices to every page
        self._log = Throttle(NOTICE_EVERY_S)       # the server's own log lines, per kind
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
        app.router.add_get("/sound", self._sound)
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
            self.refuse("host", f"refused {request.path[:60]!r}: Host {request.headers.get('Host', '')[:60]!r} "
                                "is not loopback")
            return web.Response(status=403, text="forbidden: wrong Host\n")
        query_token = request.query.get("token")
        token = query_token if query_token is not None else request.cookies.get(COOKIE)
        if not self.access.token_ok(token):
            path = request.path if request.path in ("/", "/ws/frames", "/ws/control") else repr(request.path[:60])
            self.refuse("token", f"refused {path} from {request.remote}: missing or wrong token")
            return web.Response(status=403, text="forbidden: open the URL puppet printed (with its token)\n")
        if request.path.startswith("/ws/"):
            origin = request.headers.get("Origin")
            if origin != f"http://{request.host}":
                self.refuse("origin", f"refused a WebSocket from origin {(origin or '')[:60]!r} "
                                      f"(page at http://{request.host[:60]})")
                return web.Response(status=403, text="forbidden: cross-origin WebSocket\n")
        response = await handler(request)
        if self.access.token is not None and query_token is not None and request.path == "/":
            response.set_cookie(COOKIE, query_token, httponly=True, samesite="Strict")
        return response

    def warn(self, text: str, client: str | None = None, kind: str | None = None) -> None:
        """Log a warning (stderr) and show it on the pages (client: only that viewer's page);
        any thread. Notices of one kind (default: the text) are merged, NOTICE_EVERY_S apart."""
        if self._loop is not None and threading.current_thread() is not self._thread:
            self._loop.call_soon_threadsafe(self.warn, text, client, kind)
            return
        self.warnings += 1
        kind = kind or text[:80]
        self._log_line(kind, text)
        if client is None:
            merged = self._notices.offer(kind, text, time.monotonic())
            if merged is not None:
                self._send_control(None, _notice(merged))
        else:
            viewer = self.viewers.get(client)
            if viewer is not None:
                self._notify(viewer, kind, text)

    def _notify(self, viewer: Viewer, kind: str, text: str) -> None:
        """A notice to one viewer's page, merged per kind (server thread)."""
        merged = viewer.notices.offer(kind, text, time.monotonic())
        if merged is not None and viewer.outbox is not None:
            viewer.outbox.put(_notice(merged))

    def refuse(self, kind: str, text: str) -> None:
        """A refused request: counted and logged (merged per kind), never shown to pages."""
        self.refused += 1
        self._log_line(kind, text)

    def _log_line(self, kind: str, text: str) -> None:
        line = self._log.offer(kind, text, time.monotonic())
        if line is not None:
            log.warning("view: %s", line)

    # ---- page and files -------------------------------------------------------------------------
    async def _index(self, request: web.Request) -> web.Response:
        body, kind = self._static["index.html"]
        return web.Response(body=body, content_type=kind, headers=PAGE_HEADERS)

    async def _no_icon(self, request: web.Request) -> web.Response:
        return web.Response(status=204)

    async def _sound(self, request: web.Request) -> web.StreamResponse:
        """The studio's sound file as it is (the page decodes and plays it: Web Audio); 404
        when there is none."""
        studio = getattr(self.view, "studio", None)
        path = getattr(studio, "sound_path", None)
        if path is None:
            return web.Response(status=404, text="no sound\n")
        return web.FileResponse(path, headers={"Cache-Control": "no-store",
                                               "X-Content-Type-Options": "nosniff"})

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

    def _drop(self, viewer: Viewer, stalled_s: float) -> None:
        """Cut a viewer whose socket took no data for stalled_s seconds (its handlers forget it)."""
        self.dropped_viewers += 1
        self.warn(f"viewer {viewer.number} dropped: its connection took no data for {stalled_s:.0f} s",
                  kind="dropped")
        for transport in viewer.transports.values():
            if transport is not None:
                transport.abort()
        viewer.transports.clear()
        viewer.outbox, viewer.frame_writes = None, {}

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
        viewer.transports[ws] = request.transport
        return viewer, ws

    async def _receive(self, viewer: Viewer, ws: web.WebSocketResponse, socket: str,
                       on_text) -> None:
        """Hand each text message of ws to on_text(viewer, text) until the socket closes.

        socket: its name in warnings ("frame", "control"). Messages beyond this connection's
        rate limit (INPUT_RATE_HZ) are dropped unread and counted; a binary message is ignored
        and counted; a socket error is logged.
        """
        limit = RateLimit(INPUT_RATE_HZ, INPUT_BURST)
        try:
            async for msg in ws:
                if not limit.take(time.monotonic()):
                    viewer.limited += 1
                    self._refused_input(viewer, "rate", f"too many messages on the {socket} socket: "
                                        f"dropped (at most {INPUT_RATE_HZ:.0f} per second)")
                elif msg.type == WSMsgType.TEXT:
                    on_text(viewer, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self._refused_input(viewer, "binary",
                                        f"unexpected binary message on the {socket} socket ignored")
                elif msg.type == WSMsgType.ERROR:
                    self._log_line("socket", f"viewer {viewer.number}: {socket} socket closed: {ws.exception()}")
        finally:
            viewer.transports.pop(ws, None)

    def _refused_input(self, viewer: Viewer, kind: str, problem: str, page: str | None = None) -> None:
        """Page input ignored: counted, logged (merged per kind), and noted on that viewer's
        page only (``page``: its words there, default ``problem``; never the input itself)."""
        if kind not in ("rate", "picks"):
            viewer.ignored += 1
        self.warnings += 1
        self._log_line(kind, f"viewer {viewer.number}: {problem}")
        self._notify(viewer, kind, page or problem)

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
        message = parse_message(text)
        if message is None or message.get("type") != "ack" or not isinstance(message.get("seq"), int):
            self._refused_input(viewer, "malformed", f"malformed message on the frame socket ignored: "
                                f"{text[:40]!r}", page="malformed message on the frame socket ignored")
            return
        sent = viewer.inflight.pop(message["seq"], None)
        if sent is None:
            return
        reading_t_ns, send_t_ns = sent
        now = time.monotonic_ns()
        total_ms = (now - reading_t_ns) / 1e6
        self.latency_ms.append(total_ms)
        viewer.latency_ms.append(total_ms)
        # The page measures arrival -> drawn on its own clock; the rest is transport both ways.
        drawn_ms = message.get("drawn_ms")
        if _number(drawn_ms) and 0 <= drawn_ms <= total_ms:
            to_send_ms = (send_t_ns - reading_t_ns) / 1e6
            self.latency_split.append((to_send_ms, max(total_ms - to_send_ms - drawn_ms, 0.0), drawn_ms))
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
        if viewer.control is not None and not viewer.control.closed:
            await viewer.control.close()
        viewer.control = ws
        viewer.outbox = outbox = Outbox()
        sock = request.transport.get_extra_info("socket") if request.transport is not None else None
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, CONTROL_SNDBUF)
        snapshot = self.view.snapshot()
        snapshot["viewer"] = viewer.number
        outbox.put(json.dumps(snapshot))
        writer = asyncio.ensure_future(self._pump(ws, outbox))
        try:
            await self._receive(viewer, ws, "control", self._control_message)
        finally:
            writer.cancel()
            if viewer.control is ws:
                viewer.control = None
                viewer.outbox = None
                self._forget(viewer)
        return ws

    async def _pump(self, ws, outbox: Outbox) -> None:
        """One viewer's control writer: sends its outbox in order, the panel last (latest wins)."""
        try:
            while not ws.closed:
                await outbox.ready.wait()
                outbox.ready.clear()
                while (text := outbox.take()) is not None and not ws.closed:
                    outbox.busy_since = time.monotonic()
                    await ws.send_str(text)
                    outbox.busy_since = None
        except (ConnectionError, RuntimeError):
            pass  # the socket's handler notices the close and forgets the viewer

    def _control_message(self, viewer: Viewer, text: str) -> None:
        message = parse_message(text)
        problem = check_input(message)
        if problem is not None:
            if problem.startswith("unknown"):  # logged with its type; the page is not echoed it
                self._refused_input(viewer, "unknown", f"{problem[:60]}; ignored",
                                    page="a message of a type the page never sends ignored")
            else:
                self._refused_input(viewer, "malformed", f"{problem}; ignored: {text[:40]!r}",
                                    page=f"{problem}; ignored")
            return
        if message["type"] == "pick" and not viewer.picks.take(time.monotonic()):
            viewer.limited += 1
            self._refused_input(viewer, "picks", f"too many picks: dropped (at most {PICK_RATE_HZ:.0f} "
                                "per second)")
            if viewer.outbox is not None:  # the page's pending drag turns the camera instead
                viewer.outbox.put(json.dumps({"type": "pick_miss", "key": message["key"]}))
            return
        if message["type"] in ("key", "key_edit", "retime") and not viewer.edits.take(time.monotonic()):
            viewer.limited += 1
            self._refused_input(viewer, "edits", f"too many key edits: dropped (at most "
                                f"{EDIT_RATE_HZ:.0f} per second)")
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
        send_t_ns = time.monotonic_ns()
        viewer.inflight[frame.seq] = (frame.reading_t_ns, send_t_ns)
        if len(viewer.inflight) > 4 * CREDIT:  # acks lost: forget the oldest
            for seq in sorted(viewer.inflight)[: len(viewer.inflight) - 4 * CREDIT]:
                del viewer.inflight[seq]
        data = frame_header(FLAG_DRAFT if frame.draft else 0, frame.camera, frame.seq,
                            frame.reading_t_ns, send_t_ns) + frame.jpeg
        viewer.sent += 1
        viewer.bytes_sent += len(data)
        self.bytes_sent += len(data)
        viewer.frame_writes[frame.seq] = time.monotonic()
        asyncio.ensure_future(self._write(viewer, ws, data, frame.seq))

    async def _write(self, viewer: Viewer, ws, data: bytes, seq: int) -> None:
        try:
            await ws.send_bytes(data)
        except (ConnectionError, RuntimeError) as err:
            self._log_line("gone", f"viewer {viewer.number} went away mid-stream ({type(err).__name__})")
        finally:
            viewer.frame_writes.pop(seq, None)

    # ---- panel, notices, stuck viewers ----------------------------------------------------------
    async def _panel_task(self) -> None:
        """PANEL_HZ times a second: each viewer's newest panel into its outbox (nothing awaits a
        viewer), merged notices out, viewers stuck for stall_drop_s dropped."""
        period = 1.0 / PANEL_HZ
        while True:
            await asyncio.sleep(period)
            now = time.monotonic()
            latency = self.latency_summary()
            for viewer in list(self.viewers.values()):
                stalled = self._stalled_s(viewer, now)
                if stalled >= self.stall_drop_s:
                    self._drop(viewer, stalled)
                    continue
                for text in viewer.notices.due(now):
                    if viewer.outbox is not None:
                        viewer.outbox.put(_notice(text))
                if viewer.outbox is None:
                    continue
                panel = self.view.panel(viewer.camera)
                panel["viewer"] = {"number": viewer.number, "fps": round(viewer.fps(now), 1),
                                   "drops": viewer.drops, "shown": viewer.shown,
                                   "camera": viewer.camera, "ignored": viewer.ignored,
                                   "limited": viewer.limited, "lost": viewer.outbox.lost}
                panel["latency_ms"] = latency
                panel["viewer"]["latency_ms"] = summarize_ms(viewer.latency_ms)
                viewer.outbox.put_panel(json.dumps(panel))
            for text in self._notices.due(now):
                self._send_control(None, _notice(text))
            for line in self._log.due(now):
                log.warning("view: %s", line)

    @staticmethod
    def _stalled_s(viewer: Viewer, now: float) -> float:
        """How long the oldest send to this viewer that has not finished has waited (s)."""
        starts = list(viewer.frame_writes.values())
        if viewer.outbox is not None and viewer.outbox.busy_since is not None:
            starts.append(viewer.outbox.busy_since)
        return now - min(starts) if starts else 0.0

    def latency_summary(self) -> dict:
        """Median and p99 (ms) of the newest 300 frames shown on any page."""
        return summarize_ms(list(self.latency_ms)[-300:])

    def send_to(self, client: str | None, message: dict) -> None:
        """Send a control message to one viewer (None: every viewer); any thread."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._send_control, client, json.dumps(message))

    def _send_control(self, client: str | None, text: str) -> None:
        for viewer in self.viewers.values():
            if (client is None or viewer.client == client) and viewer.outbox is not None:
                viewer.outbox.put(text)


def summarize_ms(values) -> dict:
    """{"median", "p99"} of a few hundred ms figures, rounded to 0.1 (None when empty)."""
    recent = sorted(values)
    if not recent:
        return {"median": None, "p99": None}
    return {"median": round(recent[len(recent) // 2], 1),
            "p99": round(recent[min(len(recent) - 1, math.ceil(0.99 * len(recent)) - 1)], 1)}


def _notice(text: str) -> str:
    return json.dumps({"type": "notice", "level": "warning", "text": text})


def _whole(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


#: The page's key edits (``key_edit``'s action), each the terminal's command line for it:
#: replace key index with the held pose, delete it, insert a key at frame, set its interpolation
#: or that of the keys to come.
KEY_EDITS = {"replace": "r {index}", "delete": "d {index}", "insert": "i {frame}",
             "interpolation": "m {index} {interpolation}", "new_interpolation": "m {interpolation}"}

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
    "key": {},
    "key_edit": {"action": lambda v: v in KEY_EDITS,
                 "index": lambda v: _whole(v) and 0 <= v <= MAX_FRAME,
                 "frame": lambda v: _whole(v) and 1 <= v <= MAX_FRAME,
                 "interpolation": lambda v: v in INTERPOLATIONS},
    "retime": {"index": lambda v: _whole(v) and 0 <= v <= MAX_FRAME,
               "frame": lambda v: _whole(v) and 1 <= v <= MAX_FRAME},
    "onion": {"on": lambda v: isinstance(v, bool)},
    "playhead": {"frame": lambda v: _whole(v) and 1 <= v <= MAX_FRAME},
    "studio": {"action": lambda v: isinstance(v, str) and len(v) <= 20},  # its fields: StudioDesk
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
