"""A room full of viewers and a hostile network on ``puppet demo --view``: a viewer that never
reads cannot stall another, one client's flood costs the others nothing."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import socket
from urllib.parse import urlsplit

import aiohttp

from puppet.view.protocol import MAX_HANDLES, STALL_DROP_S


def stuck_socket(url: str, path: str, client: str) -> socket.socket:
    """A WebSocket (raw TCP, a tiny receive buffer) opened on the view and then never read: a
    sleeping laptop. Returns the socket (close it when done)."""
    parts = urlsplit(url)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((parts.hostname, parts.port))
    key = base64.b64encode(os.urandom(16)).decode()
    host = f"{parts.hostname}:{parts.port}"
    sock.sendall((f"GET {path}?client={client} HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\n"
                  f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                  f"Origin: http://{host}\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += sock.recv(1)
    assert head.startswith(b"HTTP/1.1 101"), head
    return sock


def panels_between(page, start_ms: float, end_ms: float) -> int:
    return page.evaluate(f"puppetView.panelTimes.filter(t => t >= {start_ms} && t <= {end_ms}).length")


def test_a_viewer_that_never_reads_stalls_nobody_and_is_dropped(new_page, demo, tools):
    page = tools.open_view(new_page, demo)
    # The page's own panel rate, alone, over a window as long as the stall will be.
    window_ms = (STALL_DROP_S - 1) * 1000
    start = page.evaluate("performance.now()")
    tools.wait_js(page, f"performance.now() > {start} + {window_ms}")
    alone = panels_between(page, start, start + window_ms)
    assert alone > 0
    stuck = [stuck_socket(demo.url, "/ws/control", "stuck"), stuck_socket(demo.url, "/ws/frames", "stuck")]
    try:
        # The server notes the drop once the stuck viewer's socket took no data for STALL_DROP_S.
        note = tools.wait_js(page, "puppetView.notices.find(n => n.text.includes('dropped: its connection "
                                   "took no data'))", timeout=tools.WAIT_S + 10 * STALL_DROP_S)
    finally:
        for sock in stuck:
            sock.close()
    # While that viewer's sends waited, this page's panel kept coming at its own rate (within a
    # generous factor: the machine is shared); before the fix it froze for the whole stall.
    during = panels_between(page, note["t"] - window_ms, note["t"])
    assert during >= alone / 4, (during, alone)
    count = page.evaluate("puppetView.shown")
    tools.wait_js(page, f"puppetView.shown > {count} + 5")
    tools.wait_until(lambda: "dropped: its connection took no data" in demo.stderr(), what="the drop in the log")
