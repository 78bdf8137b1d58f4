"""A plain Python client of the live link (the wire module only): what the add-on does,
without Blender. Load by path (pytest runs with --import-mode=importlib)."""

from __future__ import annotations

import socket
import time

from puppet.link import wire


class Client:
    """Connects, reads the hello, then ``next()`` gives messages; ``ack(seq)`` acknowledges."""

    def __init__(self, port: int, *, host: str = "127.0.0.1", token=None, mesh=False,
                 protocol=wire.PROTOCOL, timeout=60.0, record=False, health=False):
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.reader = wire.Reader()
        self.pending = []
        self.sock.sendall(wire.encode_json(wire.CONNECT, {"protocol": protocol, "token": token,
                                                          "mesh": mesh, "name": "test",
                                                          "record": record, "health": health}))
        self.first = self.next()   # (kind, content): the hello, or an error

    def next(self):
        """The next message as (kind, decoded content); (None, None) when puppet closed."""
        while not self.pending:
            data = self.sock.recv(1 << 20)
            if not data:
                return None, None
            self.reader.feed(data)
            self.pending.extend(self.reader.messages())
        kind, body = self.pending.pop(0)
        return kind, wire.decode(kind, body)

    def ack(self, seq: int) -> None:
        """Acknowledge ``seq`` (nothing once puppet has closed)."""
        try:
            self.sock.sendall(wire.encode_ack(seq, time.monotonic()))
        except (BrokenPipeError, ConnectionResetError):
            pass

    def close(self) -> None:
        self.sock.close()
