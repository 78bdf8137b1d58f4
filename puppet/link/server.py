"""The live link's server: streams each solve to every connected client (Blender), latest wins.

    link = Link("9100", rig)             # binds now: a taken port fails before any hardware
    link.attach(pipeline, fps=60.0)      # the model's LBS matrix; the rate frames come at
    link.frame(pipeline, reading)        # after each solve (run_live's ``link=``): copies T
    link.close(); link.stats()           # reading -> applied in the client, median and p99

The loop only copies ``T`` into a ring of the last ``wire.RING`` solves and wakes the link's
thread; that thread computes the keys (``LinkPose``), encodes a frame once into preallocated
buffers and gives each client the newest frame when its socket has taken the last one (a slow
client skips frames), except frames being recorded, which each client gets in order, every one
(``wire``'s recording rule), and health messages to clients that ask.
Protocol: ``puppet.link.wire``. Address and token: ``puppet.net`` (shared with the live view):
loopback by default, beyond it a random token every client must send.
"""

from __future__ import annotations

import selectors
import socket
import threading
import time
from pathlib import Path

import numpy as np

from puppet.link import wire
from puppet.link.pose import LinkPose
from puppet.histogram import Histogram
from puppet.net.address import Access, bind, parse_address
from puppet.net.guard import parse_message

DEFAULT_PORT = 9100
CLOSE_S = 10.0  # seconds close() gives recording clients to take the frames still owed them
WINDOW = 2  # frames sent to a client and not yet acked: more wait (latest wins), never queue
READ_BYTES = 1 << 16


class _Client:
    """One connection: its reader, whether it is connected (token ok), wants the mesh, every
    frame (record) and health messages, and its send buffer (a bytearray holding the message it
    is sending, and how far). Counts: frames sent, skipped (latest wins), lost (a recording
    client more than ``wire.RING`` frames behind)."""

    def __init__(self, sock: socket.socket, address):
        self.sock, self.address = sock, address
        self.reader = wire.Reader(max_message=1 << 16)
        self.connected = False
        self.mesh = self.record = self.health = False
        self.name = "?"
        self.buffer = bytearray()
        self.view = memoryview(b"")
        self.sent_seq = -1
        self.frames = self.acked = self.skipped = self.lost = 0
        self.health_at = 0.0  # time.monotonic() of the last health message
        self.health_acked = 0  # acked then
        self.in_flight_seqs: list[int] = []  # at most wire.RING

    def in_flight(self) -> int:
        return len(self.in_flight_seqs)


class Link:
    """The link's server on ``[HOST:]PORT`` for ``rig``'s solves (see the module docstring).

    fps: the frame rate announced in the hello (the take's; ``attach`` may give the loop's);
    take_start_ns: the reading time of take time 0 (None: the first frame's, or the take's
    first reading: ``start_take``); take: the take's name for the hello (the add-on names the
    recording's action after it; None: unknown); sound: (path, offset_s) of the take's sound
    for the hello (the add-on puts it on the scene's timeline; None: none). Fields after
    close: see stats().
    """

    def __init__(self, address: str | None, rig, *, fps: float = 60.0,
                 take_start_ns: int | None = None, take: str | None = None,
                 sound: tuple | None = None):
        host, port = parse_address(address, option="--link", default_port=DEFAULT_PORT)
        self.listener = bind(host, port, option="--link")
        port = self.listener.getsockname()[1]
        self.access = Access.for_host(host, port)
        self.rig, self.fps, self.take_start_ns = rig, float(fps), take_start_ns
        self.take, self.sound = take, sound
        self.pose: LinkPose | None = None
        self._model = None
        self.latency_ms = Histogram()
        self.malformed = self.refused = self.clients_seen = self.published = 0
        self.skipped = self.lost = 0  # over every client, counted when it leaves
        self._clients: dict[socket.socket, _Client] = {}
        self._lock = threading.Lock()
        # The last wire.RING solves, slot seq % RING (written by the loop under _lock).
        self._ring_T = None
        self._ring_seq = np.full(wire.RING, -1, np.int64)
        self._ring_ns = np.zeros(wire.RING, np.int64)
        self._ring_take = np.zeros(wire.RING, np.float64)
        self._ring_flags = np.zeros(wire.RING, np.uint32)
        self._recorded_seq = -1  # the newest seq flagged RECORDING
        self._T_front = None     # read by the link's thread
        self._encoded = {False: -1, True: -1}  # seq held in _bones / _mesh
        self._bones = bytearray()
        self._mesh = bytearray()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(self.listener, selectors.EVENT_READ, "listen")
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._stop = False
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        return self.access.port

    def where(self) -> str:
        """host:port and the token clients need (beyond loopback)."""
        shown = f"{self.access.host}:{self.access.port}"
        return shown if self.access.token is None else f"{shown} token {self.access.token}"

    def attach(self, pipeline, fps: float | None = None) -> None:
        """Start serving ``pipeline``'s solves (its model gives the mesh); fps: the rate they
        come at, for the hello (None: the one given when made)."""
        if fps is not None:
            self.fps = float(fps)
        self._model = pipeline.model
        self.pose = LinkPose(self.rig, pipeline.model.lbs_matrix)
        self._ring_T = np.zeros((wire.RING, *pipeline.T.shape))
        self._T_front = np.zeros(pipeline.T.shape)
        b, n = len(self.pose.names), self.pose.n_vertices
        self._bones = bytearray(wire.frame_size(b, 0))
        self._mesh = bytearray(wire.frame_size(b, n))
        self._thread = threading.Thread(target=self._serve, name="puppet-link", daemon=True)
        self._thread.start()

    def start_take(self, t_ns: int) -> None:
        """Take time 0 is the reading at ``t_ns`` (the first one a recorder wrote), unless a
        start is already set."""
        if self.take_start_ns is None:
            self.take_start_ns = int(t_ns)

    def frame(self, pipeline, reading, take_s: float | None = None,
              recording: bool = False) -> None:
        """Publish the solve just done for ``reading`` (take_s: its take time; None: seconds
        since take_start_ns; recording: it belongs to a take being recorded, flagged
        ``wire.RECORDING``). Copies T (no allocation) and wakes the link's thread."""
        if self.pose is None:
            return
        self.start_take(reading.t_ns)
        if take_s is None:
            take_s = (reading.t_ns - self.take_start_ns) * 1e-9
        flags = wire.RECORDING if recording else 0
        with self._lock:
            seq = self.published
            slot = seq % wire.RING
            self._ring_T[slot] = pipeline.T
            self._ring_seq[slot], self._ring_ns[slot] = seq, int(reading.t_ns)
            self._ring_take[slot], self._ring_flags[slot] = float(take_s), flags
            if recording:
                self._recorded_seq = seq
            self.published += 1
        try:
            self._wake_w.send(b"\0")
        except (BlockingIOError, OSError):
            pass  # the thread is already woken

    def hello(self) -> dict:
        pose = self.pose
        return {"protocol": wire.PROTOCOL, "rig": self.rig.name, "joints": pose.names,
                "parents": pose.parents, "rest_translation": pose.rest_translations.tolist(),
                "rest_rotation": pose.rest_rotations.tolist(),
                "above": pose.above.reshape(-1, 16).tolist(),
                "armature": pose.armature.reshape(16).tolist(), "vertices": pose.n_vertices,
                "fps": self.fps, "take_start_ns": self.take_start_ns, "take": self.take,
                "sound": None if self.sound is None else
                {"path": str(Path(self.sound[0]).absolute()), "offset_s": float(self.sound[1])}}

    # -- the link's thread --------------------------------------------------------------------

    def _serve(self) -> None:
        while not self._stop:
            for key, events in self._selector.select(timeout=wire.HEALTH_S / 2):
                if key.data == "listen":
                    self._accept()
                elif key.data == "wake":
                    try:
                        while self._wake_r.recv(4096):
                            pass
                    except (BlockingIOError, OSError):
                        pass
                else:
                    client = key.data
                    if events & selectors.EVENT_READ:
                        self._receive(client)
                    if events & selectors.EVENT_WRITE and client.sock in self._clients:
                        self._send(client)
            newest = self.published - 1
            now = time.monotonic()
            for client in list(self._clients.values()):
                if not client.connected or client.view:
                    continue
                if client.health and now - client.health_at >= wire.HEALTH_S:
                    self._start(client, wire.encode_json(wire.HEALTH, self._health(client, now)))
                    continue
                seq = self._next_seq(client, newest)
                if seq is not None:
                    self._start_frame(client, seq)

    def _next_seq(self, client: _Client, newest: int) -> int | None:
        """The frame to send ``client`` now, or None: the next one in order when it is
        recording or asked for every frame (none lost unless RING behind), else the newest
        (latest wins, within WINDOW in flight)."""
        first = client.sent_seq + 1
        if first > newest:
            return None
        if newest - first >= wire.RING:
            lost = newest - wire.RING + 1 - first
            client.lost += lost
            first += lost
        queued = first if client.record else None
        if queued is None and self._recorded_seq >= first:  # the first recorded frame unsent
            queued = next(seq for seq in range(first, newest + 1)
                          if self._ring_flags[seq % wire.RING] & wire.RECORDING)
        if queued is not None:
            return queued if client.in_flight() < wire.RING else None
        if client.in_flight() >= WINDOW:
            return None
        client.skipped += newest - first
        return newest

    def _health(self, client: _Client, now: float) -> dict:
        h = self.latency_ms
        rate = (client.acked - client.health_acked) / max(now - client.health_at, 1e-3)
        if not client.health_at:
            rate = 0.0
        client.health_at, client.health_acked = now, client.acked
        return {"applied_median_ms": round(h.percentile(50), 3) if h.count else None,
                "applied_p99_ms": round(h.percentile(99), 3) if h.count else None,
                "acked": client.acked, "published": self.published, "sent": client.frames,
                "skipped": client.skipped, "lost": client.lost, "acked_per_s": round(rate, 2)}

    def _accept(self) -> None:
        try:
            sock, address = self.listener.accept()
        except (BlockingIOError, OSError):
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = _Client(sock, address)
        self._clients[sock] = client
        self._selector.register(sock, selectors.EVENT_READ, client)

    def _drop(self, client: _Client) -> None:
        if self._clients.pop(client.sock, None) is not None:
            self.skipped += client.skipped
            self.lost += client.lost
        try:
            self._selector.unregister(client.sock)
        except (KeyError, ValueError):
            pass
        client.sock.close()

    def _receive(self, client: _Client) -> None:
        try:
            data = client.sock.recv(READ_BYTES)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._drop(client)
            return
        client.reader.feed(data)
        try:
            for kind, body in client.reader.messages():
                self._handle(client, kind, body)
                if client.sock not in self._clients:
                    return
        except wire.WireError:
            self.malformed += 1
            self._drop(client)

    def _handle(self, client: _Client, kind: bytes, body: bytes) -> None:
        if kind == wire.ACK_KIND and client.connected:
            try:
                seq, _applied = wire.decode(kind, body)
            except ValueError:
                self.malformed += 1
                return
            if seq in client.in_flight_seqs:  # it and every older frame are done with
                del client.in_flight_seqs[:client.in_flight_seqs.index(seq) + 1]
            slot = seq % wire.RING
            if self._ring_seq[slot] == seq:
                self.latency_ms.add((time.monotonic_ns() - int(self._ring_ns[slot])) / 1e6)
                client.acked += 1
            return
        message = None
        if kind in (wire.CONNECT, wire.MESH):
            message = parse_message(body.decode("utf-8", "replace"))
        if message is None:
            self.malformed += 1
            return
        if kind == wire.MESH and client.connected:
            client.mesh = bool(message.get("mesh"))
            client.record = bool(message.get("record", client.record))
        elif kind == wire.CONNECT and not client.connected:
            token = message.get("token")
            if message.get("protocol") != wire.PROTOCOL:
                self._refuse(client, f"protocol {message.get('protocol')!r} is not supported; "
                                     f"this puppet speaks protocol {wire.PROTOCOL}")
            elif not self.access.token_ok(token if isinstance(token, str) else None):
                self.refused += 1
                self._refuse(client, "token refused: give the token puppet printed")
            else:
                client.connected, client.mesh = True, bool(message.get("mesh"))
                client.record = bool(message.get("record"))
                client.health = bool(message.get("health"))
                client.name = str(message.get("name", "?"))[:64]
                client.sent_seq = max(self.published - 2, -1)  # from the newest frame on
                self.clients_seen += 1
                client.sock.setblocking(True)
                client.sock.settimeout(5.0)
                try:
                    client.sock.sendall(wire.encode_json(wire.HELLO, self.hello()))
                except OSError:
                    self._drop(client)
                    return
                client.sock.setblocking(False)

    def _refuse(self, client: _Client, text: str) -> None:
        try:
            client.sock.send(wire.encode_json(wire.ERROR, {"error": text}))
        except OSError:
            pass
        self._drop(client)

    def _encode(self, seq: int, mesh: bool) -> bytearray | None:
        """The frame message of solve ``seq`` (keys; the vertices when ``mesh``), encoded once
        into the bones' or the mesh's buffer; None when the loop has written over its slot."""
        buffer = self._mesh if mesh else self._bones
        if self._encoded[mesh] == seq:
            return buffer
        slot = seq % wire.RING
        with self._lock:
            if self._ring_seq[slot] != seq:
                return None
            self._T_front[...] = self._ring_T[slot]
            reading_ns, take_s = int(self._ring_ns[slot]), float(self._ring_take[slot])
            flags = int(self._ring_flags[slot])
        pose = self.pose
        pose.update(self._T_front, mesh)
        b, n = len(pose.names), pose.n_vertices if mesh else 0
        at = wire.pack_frame_header(buffer, seq, reading_ns, take_s, b, n, flags)
        np.frombuffer(buffer, np.float64, 3 * b, at)[...] = pose.translations.reshape(-1)
        np.frombuffer(buffer, np.float64, 4 * b, at + 24 * b)[...] = pose.rotations.reshape(-1)
        if mesh:
            np.frombuffer(buffer, np.float32, 3 * n, at + 56 * b)[...] = pose.vertices.reshape(-1)
        self._encoded[mesh] = seq
        return buffer

    def _start_frame(self, client: _Client, seq: int) -> None:
        source = self._encode(seq, client.mesh)
        client.sent_seq = seq
        if source is None:
            client.lost += 1
            return
        client.in_flight_seqs.append(seq)
        client.frames += 1
        self._start(client, source)

    def _start(self, client: _Client, message) -> None:
        """Begin sending ``message`` (copied into the client's buffer, which grows only when a
        message is longer than any before)."""
        if len(client.buffer) < len(message):
            client.buffer = bytearray(len(message))  # once per client and mode
        client.buffer[:len(message)] = message
        client.view = memoryview(client.buffer)[:len(message)]
        self._send(client)

    def _send(self, client: _Client) -> None:
        try:
            sent = client.sock.send(client.view)
        except BlockingIOError:
            sent = 0
        except OSError:
            self._drop(client)
            return
        client.view = client.view[sent:]
        if not client.view:
            self._selector.modify(client.sock, selectors.EVENT_READ, client)
        else:
            self._selector.modify(client.sock, selectors.EVENT_READ | selectors.EVENT_WRITE, client)

    # -- end ----------------------------------------------------------------------------------

    def close(self, reason: str = "puppet stopped") -> None:
        """Stop the thread, say bye to every client, close every socket (idempotent)."""
        if self._stop and self._thread is None:
            return
        self._stop = True
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        bye = wire.encode_json(wire.BYE, {"reason": reason})
        deadline = time.monotonic() + CLOSE_S
        for client in list(self._clients.values()):
            if client.connected:
                try:
                    client.sock.setblocking(True)
                    client.sock.settimeout(1.0)
                    if client.view:
                        client.sock.sendall(client.view)
                    client.in_flight_seqs.clear()  # no acks are read now
                    while time.monotonic() < deadline:  # what a recording client is owed
                        seq = self._next_seq(client, self.published - 1)
                        if seq is None:
                            break
                        message = self._encode(seq, client.mesh)
                        client.sent_seq = seq
                        if message is not None:
                            client.sock.settimeout(max(deadline - time.monotonic(), 0.01))
                            client.sock.sendall(message)
                    client.sock.settimeout(1.0)
                    client.sock.sendall(bye)
                except OSError:
                    pass
            self._drop(client)
        self._selector.close()
        self.listener.close()
        self._wake_r.close()
        self._wake_w.close()

    def stats(self) -> dict:
        """What the link did: clients, frames published / sent / acked / skipped, reading ->
        applied (ack received) median and p99 in ms, malformed messages, refused tokens."""
        h = self.latency_ms
        return {"clients": self.clients_seen, "published": self.published, "acked": h.count,
                "applied_median_ms": round(h.percentile(50), 3) if h.count else None,
                "applied_p99_ms": round(h.percentile(99), 3) if h.count else None,
                "skipped": self.skipped, "lost": self.lost,
                "malformed": self.malformed, "refused": self.refused}

    def text(self) -> str:
        s = self.stats()
        if not s["acked"]:
            return (f"{s['clients']} client(s), {s['published']} frames published, none applied "
                    "(acknowledged)")
        return (f"{s['clients']} client(s), {s['published']} frames published, {s['acked']} "
                f"applied; reading->applied median {s['applied_median_ms']} ms, "
                f"p99 {s['applied_p99_ms']} ms")
