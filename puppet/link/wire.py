"""The live link's wire protocol, version 2: puppet streams poses to Blender over TCP.

Standard library only (struct, json): this one file is shipped verbatim inside the Blender add-on
(``puppet blender addon``) and used by puppet's server, so both ends speak the same bytes.

Every message is ``length (uint32, big-endian) | kind (1 byte) | body``, length counting kind and
body, at most MAX_MESSAGE bytes. Kinds:

  client -> puppet
    b"C" connect  JSON {"protocol": 2, "token": str|null, "mesh": bool, "name": str,
                  "record": bool (optional), "health": bool (optional)}
    b"M" mesh     JSON {"mesh": bool, "record": bool (optional)}: start / stop sending the
                  vertices; record: send every frame from now on (the client keys them all)
    b"A" ack      ACK: seq (uint64), applied_s (float64, the client's clock): a frame applied
  puppet -> client
    b"H" hello    JSON {"protocol", "rig", "joints": [names], "parents": [int],
                  "rest_translation": [[x, y, z]], "rest_rotation": [[x, y, z, w]],
                  "above": [[16 floats]], "armature": [16 floats], "vertices": n,
                  "fps", "take_start_ns", "take": str|null (the take's name, when known),
                  "sound": {"path": str, "offset_s": float}|null (optional: the take's sound
                  file, absolute, on puppet's machine, and where in it the take's time 0 is)}
    b"F" frame    FRAME header: seq (uint64), reading_ns (int64, puppet's monotonic clock),
                  take_s (float64, seconds into the take), joints b (uint32), vertices n
                  (uint32), flags (uint32: RECORDING); then b × 3 float64 local translations,
                  b × 4 float64 local rotations (x, y, z, w), then n × 3 float32 vertices (0
                  unless the client asked for the mesh)
    b"E" error    JSON {"error": str}: refused (bad token, protocol); puppet closes the connection
    b"B" bye      JSON {"reason": str}: puppet stops streaming
    b"S" health   JSON {"applied_median_ms", "applied_p99_ms" (puppet's reading -> applied,
                  as its summary computes them; null before an ack), "acked", "published",
                  "sent", "skipped", "lost", "acked_per_s" (this client's, over the last
                  interval)}: every HEALTH_S to a client that connected with "health": true

Joint transforms are each joint's glTF node translation and rotation relative to its parent
node, as ``puppet export --gltf`` writes its keys (Y up, model units). The hello places them:
``parents`` is each joint's nearest joint above (-1: none) and ``above`` (4 × 4, row-major) the
rest transform of the joint's parent node in that joint's space, or, for a joint with no joint
above, in the space of the armature node (the node Blender's glTF importer makes the armature
object; ``armature`` is its rest world, identity when the scene root): so a joint's posed
transform in the armature's space is ``G_parent · above · (translation, rotation)``. Vertices are
the solver's deformed mesh in the model frame (the file's world), in the character file's
vertex order.

Recording: a frame with flags & RECORDING is part of a take being recorded (``puppet live
--record``); its take_s is its reading's time on the take's time line (seconds after the take's
first reading, every gap between readings longer than MAX_GAP_S cut to it, as playback cuts
them), so the client keys it at scene frame start + take_s × scene fps, where
``puppet export`` of that take puts it, and places the hello's sound (if any) so that its
sample 0 plays at frame start - offset_s × scene fps. fps in the hello is the rate frames come
at: the take's (play) or the live loop's target (live, demo). Latest wins: puppet keeps at
most 2 frames unacknowledged per client and then sends the newest one (a slow client skips
frames, none queue); the client applies the newest frame it has and acks it (acking only
that one acks the older ones too). Except while recording: a frame flagged RECORDING, and every
frame to a client that asked for "record", is never skipped: puppet keeps the last RING frames'
solves and sends each in order (a client more than RING frames behind loses the oldest, counted
as "lost" in the health message), so the client keys every one when it catches up.
"""

from __future__ import annotations

import json
import struct

PROTOCOL = 2
MAX_MESSAGE = 64 << 20  # bytes: a 5-million-vertex mesh frame fits
LENGTH = struct.Struct(">I")
FRAME = struct.Struct("<QqdIII")
RECORDING = 1  # frame flag: puppet is recording the take this frame belongs to
ACK = struct.Struct("<Qd")

RING = 512  # frames puppet keeps for a recording client that is behind (8.5 s at 60 fps)
HEALTH_S = 0.5  # seconds between health messages

CONNECT, MESH, ACK_KIND, HELLO, FRAME_KIND, ERROR, BYE, HEALTH = (
    b"C", b"M", b"A", b"H", b"F", b"E", b"B", b"S")
JSON_KINDS = (CONNECT, MESH, HELLO, ERROR, BYE, HEALTH)


class WireError(Exception):
    """A message that breaks the protocol (the stream cannot continue past it)."""


def frame_size(joints: int, vertices: int) -> int:
    """Bytes of a frame message, length prefix included."""
    return LENGTH.size + 1 + FRAME.size + joints * 7 * 8 + vertices * 3 * 4


def encode_json(kind: bytes, obj: dict) -> bytes:
    """One JSON message."""
    body = json.dumps(obj, separators=(",", ":")).encode()
    return LENGTH.pack(1 + len(body)) + kind + body


def encode_ack(seq: int, applied_s: float) -> bytes:
    return LENGTH.pack(1 + ACK.size) + ACK_KIND + ACK.pack(seq, applied_s)


def pack_frame_header(buffer, seq: int, reading_ns: int, take_s: float, joints: int,
                      vertices: int, flags: int = 0) -> int:
    """Write a frame's length, kind and header at the start of ``buffer``; the offset where the
    joint translations go."""
    LENGTH.pack_into(buffer, 0, frame_size(joints, vertices) - LENGTH.size)
    buffer[LENGTH.size] = FRAME_KIND[0]
    FRAME.pack_into(buffer, LENGTH.size + 1, seq, reading_ns, take_s, joints, vertices, flags)
    return LENGTH.size + 1 + FRAME.size


def encode_frame(seq: int, reading_ns: int, take_s: float, translations, rotations,
                 vertices=None, flags: int = 0) -> bytes:
    """A frame from sequences: translations [(x, y, z)] * b, rotations [(x, y, z, w)] * b,
    vertices None or [(x, y, z)] * n (plain Python; puppet's server fills buffers instead)."""
    b, n = len(translations), 0 if vertices is None else len(vertices)
    out = bytearray(frame_size(b, n))
    at = pack_frame_header(out, seq, reading_ns, take_s, b, n, flags)
    struct.pack_into(f"<{3 * b}d", out, at, *[x for t in translations for x in t])
    struct.pack_into(f"<{4 * b}d", out, at + 24 * b, *[x for q in rotations for x in q])
    if n:
        struct.pack_into(f"<{3 * n}f", out, at + 56 * b, *[x for v in vertices for x in v])
    return bytes(out)


class Frame:
    """A decoded frame: seq, reading_ns, take_s, flags, translations (b × 3 floats, flat
    tuple), rotations (b × 4, flat, x y z w), vertices (a memoryview of n × 3 float32, or None);
    recording: flags & RECORDING."""

    __slots__ = ("seq", "reading_ns", "take_s", "flags", "translations", "rotations", "vertices",
                 "count")

    def __init__(self, body: bytes):
        if len(body) < FRAME.size:
            raise ValueError("frame shorter than its header")
        self.seq, self.reading_ns, self.take_s, b, n, self.flags = FRAME.unpack_from(body, 0)
        if len(body) != FRAME.size + b * 56 + n * 12:
            raise ValueError(f"frame of {len(body)} bytes does not hold {b} joints and "
                             f"{n} vertices")
        self.count = b
        self.translations = struct.unpack_from(f"<{3 * b}d", body, FRAME.size)
        self.rotations = struct.unpack_from(f"<{4 * b}d", body, FRAME.size + 24 * b)
        self.vertices = memoryview(body)[FRAME.size + 56 * b:].cast("f") if n else None

    @property
    def recording(self) -> bool:
        return bool(self.flags & RECORDING)


def decode(kind: bytes, body: bytes):
    """A message's content: a dict (JSON kinds), a Frame, or (seq, applied_s) for an ack.
    ValueError for a malformed body (the caller counts it and goes on)."""
    if kind in JSON_KINDS:
        try:
            obj = json.loads(body.decode())
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
            raise ValueError(f"bad JSON: {err}") from None
        if not isinstance(obj, dict):
            raise ValueError("JSON message is not an object")
        return obj
    if kind == FRAME_KIND:
        return Frame(body)
    if kind == ACK_KIND:
        if len(body) != ACK.size:
            raise ValueError("ack of the wrong size")
        return ACK.unpack_from(body, 0)
    raise ValueError(f"unknown message kind {bytes(kind)!r}")


class Reader:
    """Splits a byte stream into messages. ``feed(data)`` then ``messages()`` yields (kind, body
    bytes) for each complete one. WireError when a length is
    beyond MAX_MESSAGE or zero: the stream is lost."""

    def __init__(self, max_message: int = MAX_MESSAGE):
        self.max_message = max_message
        self._buffer = bytearray()
        self._start = 0

    def feed(self, data) -> None:
        if self._start:
            del self._buffer[:self._start]
            self._start = 0
        self._buffer += data

    def messages(self):
        buffer = self._buffer
        while len(buffer) - self._start >= LENGTH.size:
            (length,) = LENGTH.unpack_from(buffer, self._start)
            if length == 0 or length > self.max_message:
                raise WireError(f"message length {length} outside 1..{self.max_message}")
            end = self._start + LENGTH.size + length
            if len(buffer) < end:
                return
            at = self._start + LENGTH.size
            with memoryview(buffer) as view:  # one copy of the body (a slice would be two)
                kind, body = bytes(view[at:at + 1]), bytes(view[at + 1:end])
            self._start = end
            yield kind, body
