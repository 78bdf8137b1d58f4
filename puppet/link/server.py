"""The live link's server: streams each solve to every connected client (Blender), latest wins.

    link = Link("9100", rig)             # binds now: a taken port fails before any hardware
    link.attach(pipeline, fps=60.0)      # the model's LBS matrix; the rate frames come at
    link.frame(pipeline, reading)        # after each solve (run_live's ``link=``): copies T
    link.close(); link.stats()           # reading -> applied in the client, median and p99

The loop only copies ``T`` into a slot and wakes the link's thread; that thread computes the
keys (``LinkPose``), encodes the frame once into preallocated buffers and gives each client the
newest frame when its socket has taken the last one (a slow client skips frames, never queues).
Protocol: ``puppet.link.wire``. Address, token and flood guard: the ones the live view uses
(``puppet.net``): loopback by default, beyond it a random token every client must send.
"""

from __future__ import annotations

import selectors
import socket
import threading
import time

import numpy as np

from puppet.link import wire
from puppet.link.pose import LinkPose
from puppet.loop.histogram import Histogram
from puppet.net.address import Access, bind, parse_address
from puppet.net.guard import parse_message

DEFAULT_PORT = 9100
ACK_RING = 4096  # frames in flight whose reading time is kept for their ack
WINDOW = 2  # frames sent to a client and not yet acked: more wait (latest wins), never queue
READ_BYTES = 1 << 16


class _Client:
    """One connection: its reader, whether it is connected (token ok), wants the mesh, and its
    send buffer (a preallocated bytearray holding the frame it is sending, and how far)."""

    def __init__(self, sock: socket.socket, address):
        self.sock, self.address = sock, address
        self.reader = wire.Reader(max_message=1 << 16)
        self.connected = False
        self.mesh = False
        self.name = "?"
        self.buffer = bytearray()
        self.view = memoryview(b"")
        self.sent_seq = -1
        self.frames = self.acked = self.skipped = 0
        self.acked_seq = -1
        self.in_flight_seqs: list[int] = []

    def in_flight(self) -> int:
        return len(self.in_flight_seqs)


class Link:
    """The link's server on ``[HOST:]PORT`` for ``rig``'s solves (see the module docstring).

    fps: the frame rate announced in the hello (the take's; ``attach`` may give the loop's);
    take_start_ns: the reading time of take time 0 (None: the first frame's, or the take's
    first reading: ``start_take``). Fields after close: see stats().
    """

    def __init__(self, address: str | None, rig, *, fps: float = 60.0,
                 take_start_ns: int | None = None):
        host, port = parse_address(address, option="--link", default_port=DEFAULT_PORT)
        self.listener = bind(host, port, option="--link")
        port = self.listener.getsockname()[1]
        self.access = Access.for_host(host, port)
        self.rig, self.fps, self.take_start_ns = rig, float(fps), take_start_ns
        self.pose: LinkPose | None = None
        self._model = None
        self.latency_ms = Histogram()
        self.malformed = self.refused = self.clients_seen = self.published = 0
        self._clients: dict[socket.socket, _Client] = {}
        self._lock = threading.Lock()
        self._T_back = None      # written by the loop
        self._T_front = None     # read by the link's thread
        self._slot = (-1, 0, 0.0, 0)  # (seq, reading_ns, take_s, flags) of _T_back
        self._encoded_seq = -1
        self._bones = bytearray()
        self._mesh = bytearray()
        self._ring_seq = np.full(ACK_RING, -1, np.int64)
        self._ring_ns = np.zeros(ACK_RING, np.int64)
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
        self._T_back = np.zeros(pipeline.T.shape)
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
            self._T_back[...] = pipeline.T
            self._slot = (self.published, int(reading.t_ns), float(take_s), flags)
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
                "fps": self.fps, "take_start_ns": self.take_start_ns}

    # -- the link's thread --------------------------------------------------------------------

    def _serve(self) -> None:
        while not self._stop:
            for key, events in self._selector.select(timeout=0.5):
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
            self._encode()
            for client in list(self._clients.values()):
                if (client.connected and not client.view and client.sent_seq < self._encoded_seq
                        and client.in_flight() < WINDOW):
                    self._start_frame(client)

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
        self._clients.pop(client.sock, None)
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
            slot = seq % ACK_RING
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
                client.name = str(message.get("name", "?"))[:64]
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

    def _encode(self) -> None:
        """Encode the newest published frame once (keys; the mesh when a client wants it)."""
        with self._lock:
            seq, reading_ns, take_s, flags = self._slot
            if seq <= self._encoded_seq:
                return
            self._T_front[...] = self._T_back
        mesh = any(c.mesh for c in self._clients.values() if c.connected)
        pose = self.pose
        pose.update(self._T_front, mesh)
        b, n = len(pose.names), pose.n_vertices
        for buffer, vertices in ((self._bones, 0), (self._mesh, n)):
            if vertices and not mesh:
                continue
            at = wire.pack_frame_header(buffer, seq, reading_ns, take_s, b, vertices, flags)
            np.frombuffer(buffer, np.float64, 3 * b, at)[...] = pose.translations.reshape(-1)
            np.frombuffer(buffer, np.float64, 4 * b, at + 24 * b)[...] = pose.rotations.reshape(-1)
            if vertices:
                points = np.frombuffer(buffer, np.float32, 3 * n, at + 56 * b)
                points[...] = pose.vertices.reshape(-1)
        self._ring_seq[seq % ACK_RING] = seq
        self._ring_ns[seq % ACK_RING] = reading_ns
        self._encoded_seq = seq

    def _start_frame(self, client: _Client) -> None:
        source = self._mesh if client.mesh else self._bones
        if len(client.buffer) != len(source):
            client.buffer = bytearray(len(source))  # once per client and mode
        client.buffer[:] = source
        if client.sent_seq >= 0:
            client.skipped += self._encoded_seq - client.sent_seq - 1
        client.sent_seq = self._encoded_seq
        client.in_flight_seqs.append(client.sent_seq)
        client.view = memoryview(client.buffer)
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
            client.frames += 1
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
        for client in list(self._clients.values()):
            if client.connected:
                try:
                    client.sock.setblocking(True)
                    client.sock.settimeout(1.0)
                    if client.view:
                        client.sock.sendall(client.view)
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
                "malformed": self.malformed, "refused": self.refused}

    def text(self) -> str:
        s = self.stats()
        if not s["acked"]:
            return (f"{s['clients']} client(s), {s['published']} frames published, none applied "
                    "(acknowledged)")
        return (f"{s['clients']} client(s), {s['published']} frames published, {s['acked']} "
                f"applied; reading->applied median {s['applied_median_ms']} ms, "
                f"p99 {s['applied_p99_ms']} ms")
