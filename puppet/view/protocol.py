"""The wire format between the view's server and its page.

Frames (``/ws/frames``, server to page): one binary WebSocket message per frame, a fixed
little-endian header then the JPEG bytes (no base64, no JSON):

    offset 0   uint8   type (FRAME_JPEG)
    offset 1   uint8   flags (FLAG_DRAFT: a cheaper frame while the camera or a handle moves)
    offset 2   uint16  camera id (0: the shared camera)
    offset 4   uint32  sequence number (per view, increasing)
    offset 8   int64   reading time, ns (the servo reading the frame shows; server's monotonic clock)
    offset 16  int64   send time, ns (server's monotonic clock)
    offset 24  ...     JPEG

The page answers each frame once it is drawn with ``{"type": "ack", "seq": N, "drawn_ms": D}``
on the same socket (D: arrival to drawn, ms, on the page's clock); the server computes each
tab's reading-to-drawn latency on its own clock and splits it: reading -> send (server),
send -> arrival and the ack back (transport), arrival -> drawn (the page's D). Control (``/ws/control``)
carries small JSON messages both ways: panel, snapshot, faults, handles; input from the page.
"""

from __future__ import annotations

import struct

#: Where the view listens when ``--view`` names no port (``puppet.net.address``).
DEFAULT_PORT = 8765

FRAME_HEADER = struct.Struct("<BBHIqq")
FRAME_JPEG = 1
FLAG_DRAFT = 1

#: Frames a viewer may have in flight (sent, not yet acknowledged).
CREDIT = 2
#: Largest message the page may send (bytes); bigger ones close that socket.
MAX_CLIENT_MESSAGE = 4096
#: Panel messages per second: about as fast as a person reads numbers. Each one restyles and
#: repaints the page's servo table: at 15 Hz that was a quarter of a headless Chromium tab's CPU
#: (3 tabs beside the loop on 2 cores: 27 page fps instead of 31).
PANEL_HZ = 5.0

# ---- what one viewer may cost the others (per connection; see puppet.net.guard) ----------
#: Messages per second a page may send on either socket, and at once: the page merges camera
#: moves and drags into one message per animation frame (<= 60 Hz each) and acknowledges each
#: frame (<= the view's max fps). Messages above the limit are dropped unread and counted.
INPUT_RATE_HZ, INPUT_BURST = 120.0, 240
#: Picks (a press on the character: a GPU pick and a solver refactor) per second, and at once.
PICK_RATE_HZ, PICK_BURST = 4.0, 8
#: Key edits (a key, a retime: each rewrites the shot file) per second, and at once.
EDIT_RATE_HZ, EDIT_BURST = 4.0, 8
#: Handles the view holds at most; a pick beyond them is refused with a notice.
MAX_HANDLES = 16
#: A viewer whose socket takes no data (a send waits) for this long is dropped, with a note.
STALL_DROP_S = 10.0
#: The environment setting that replaces STALL_DROP_S (seconds > 0; tests of the mechanism).
STALL_DROP_ENV = "PUPPET_VIEW_STALL_DROP_S"
#: Kernel send buffer per control socket (bytes; Linux doubles it): a stuck viewer's socket is
#: full after this (and asyncio's 64 KiB) instead of after megabytes of autotuned buffer.
CONTROL_SNDBUF = 32 * 1024
#: Control messages (other than the panel, which is latest-wins) waiting per viewer; beyond it
#: the oldest are dropped (a snapshot on reconnect has the state).
OUTBOX_MESSAGES = 64
#: Notices of one kind go out at most once per this many seconds; the rest are merged.
NOTICE_EVERY_S = 2.0


def frame_header(flags: int, camera: int, seq: int, reading_t_ns: int, send_t_ns: int) -> bytes:
    return FRAME_HEADER.pack(FRAME_JPEG, flags, camera, seq & 0xFFFFFFFF, reading_t_ns, send_t_ns)


def stall_drop_s() -> float:
    """Seconds a viewer's socket may take no data before it is dropped: STALL_DROP_S, or
    ``$PUPPET_VIEW_STALL_DROP_S`` when set (ViewError naming it when not a number of seconds)."""
    from puppet.limits import SECONDS, from_environment
    from puppet.view.errors import ViewError

    try:
        return from_environment(STALL_DROP_ENV, STALL_DROP_S, SECONDS)
    except ValueError as err:
        raise ViewError(str(err)) from None
