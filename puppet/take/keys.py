"""Key poses in a take: a shot is a take whose keys sit on a channel of their own.

Channel ``/puppet/keys`` (schema ``puppet.Key``, jsonschema; channel metadata ``fps``: the
shot's frames per second) holds one JSON message per key, in frame order::

    {"index": 0, "frame": 1, "interpolation": "linear", "ticks": [...], "ok": [...], "crc": "..."}

index: the key's id, stable for the shot's life (``Key.id``: the first keys are 0, 1, 2, ...;
a key made later gets the next unused id, a deleted key's id is not reused, and edits address
keys by it, so a skipped damaged key renumbers nothing); frame: the shot frame it lands on (1-based, at the
shot's fps; frame 1 is the first key, strictly increasing); ticks: (k,) int encoder counts in
the take's ids order, each the median of the readings over the hold window
(``puppet.keys.capture.HOLD_S``); ok: (k,) bool; interpolation: how the frames from this key to
the next are filled: "linear" (slerp of each sensed joint's rotation), "smooth" (a C2 spline in
rotation space through the keys) or "step" (hold this key); crc: CRC-32 (8 hex digits) of the
message's other entries (``key_checksum``). log_time = the key's time on the shot's time line,
``(frame − 1) / fps`` seconds (``key_time_ns``).

The readings channel of a shot holds the same keys as readings (one per key, at the key's
time), so a reader that knows only readings plays the key poses with ticks interpolated. A
damaged key message loses only itself (``read_keys`` lists what it skipped, and keeps its bytes:
an edited shot is written with them, so an edit never drops what it could not read).

A shot spans at most ``puppet.limits.SHOT_SECONDS`` (its last key's time): a key beyond is
refused, naming it (``check_frames``).
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet.take.errors import TakeError

KEY_TOPIC = "/puppet/keys"
KEY_SCHEMA_NAME = "puppet.Key"
KEY_SCHEMA_ENCODING = "jsonschema"
KEY_SCHEMA = json.dumps({
    "type": "object",
    "properties": {"index": {"type": "integer"}, "frame": {"type": "integer"},
                   "interpolation": {"type": "string"},
                   "ticks": {"type": "array", "items": {"type": "integer"}},
                   "ok": {"type": "array", "items": {"type": "boolean"}},
                   "crc": {"type": "string"}},
    "required": ["index", "frame", "interpolation", "ticks", "ok", "crc"],
})
KEY_MESSAGE_ENCODING = "json"
INTERPOLATIONS = ("linear", "smooth", "step")
"""How the frames after a key are filled, up to the next key (see the module docstring)."""
MAX_FRAME = 10_000_000
"""Largest key frame whatever the fps (about 4.6 days at 24 fps): a larger one is a typo; the
shot's length bound (``puppet.limits.SHOT_SECONDS``) is checked at the shot's fps."""


@dataclass
class Key:
    """One key pose of a shot.

    frame: 1-based shot frame. ticks: (k,) int32 in the take's ids order. ok: (k,) bool.
    interpolation: one of INTERPOLATIONS (fills the frames from this key to the next).
    id: the key's stable id in its shot (see the module docstring); edits address keys by it.
    """

    frame: int
    ticks: np.ndarray
    ok: np.ndarray
    interpolation: str = "linear"
    id: int | None = None  # stable id (the message's index); None: given one by Keys


@dataclass
class Keys:
    """The keys of a shot, in frame order, and what reading them skipped.

    fps: the shot's frames per second. keys: [Key], frames strictly increasing.
    skipped: ["key message at byte N: reason"] for damaged key messages (empty when clean).
    """

    fps: float
    keys: list[Key]
    skipped: list[str] = field(default_factory=list)
    damaged: list[tuple[int, bytes]] = field(default_factory=list)  # (log time ns, message)

    def __post_init__(self) -> None:
        """Keys without an id get the next unused ones, in order."""
        if any(k.id is None for k in self.keys):
            from dataclasses import replace

            next_id = self.next_id()
            named = []
            for key in self.keys:
                if key.id is None:
                    key, next_id = replace(key, id=next_id), next_id + 1
                named.append(key)
            self.keys = named

    def next_id(self) -> int:
        """The id a new key gets: one above every id used (a deleted key's is not reused)."""
        used = [k.id for k in self.keys if k.id is not None]
        return max(used, default=-1) + 1

    def position(self, key_id: int, source) -> int:
        """Where the key with id ``key_id`` is in ``keys``; TakeError naming the ids there are."""
        for i, key in enumerate(self.keys):
            if key.id == int(key_id):
                return i
        ids = ", ".join(str(k.id) for k in self.keys)
        raise TakeError(source, f"no key {key_id}: the shot's keys are {ids}" if self.keys
                        else f"no key {key_id}: the shot has no keys")

    def times_ns(self, t0_ns: int = 0) -> np.ndarray:
        """(K,) int64 each key's time on the shot's time line, ns (t0_ns for frame 1)."""
        return np.array([t0_ns + key_time_ns(k.frame, self.fps) for k in self.keys], np.int64)


def key_time_ns(frame: int, fps: float) -> int:
    """Time of shot frame ``frame`` (1-based) after frame 1, ns."""
    return int(round((int(frame) - 1) * 1e9 / float(fps)))


def check_interpolation(value: str, source) -> str:
    """value, or TakeError naming source unless it is one of INTERPOLATIONS."""
    if value not in INTERPOLATIONS:
        raise TakeError(source, f"interpolation {value!r} is not one of {', '.join(INTERPOLATIONS)}")
    return value


def last_frame(fps: float) -> int:
    """The last frame a shot at ``fps`` may have a key on (``puppet.limits.SHOT_SECONDS``)."""
    from puppet.limits import SHOT_SECONDS

    return min(MAX_FRAME, 1 + int(SHOT_SECONDS.hi * float(fps) + 1e-9))


def check_frames(frames, source, fps: float | None = None, ids=None) -> None:
    """TakeError naming source unless frames are >= 1, strictly increasing and within the
    shot's length (``last_frame(fps)``; MAX_FRAME when fps is None). Keys are named by their
    ids (``ids``; their places when None): two on one frame, out of order, or too late."""
    from puppet.limits import SHOT_SECONDS

    names = list(ids) if ids is not None else list(range(len(frames)))
    last = last_frame(fps) if fps is not None else MAX_FRAME
    for i, f in enumerate(frames):
        if not 1 <= int(f) <= last:
            why = "" if fps is None else (
                f" ({(int(f) - 1) / float(fps):g} s into the shot at {float(fps):g} fps; a shot "
                f"spans at most {SHOT_SECONDS.hi:g} s, puppet.limits.SHOT_SECONDS)")
            raise TakeError(source, f"key {names[i]}: frame {f} is not within 1..{last}{why}")
        if i and int(f) <= int(frames[i - 1]):
            word = "on the same frame as" if int(f) == int(frames[i - 1]) else "before"
            raise TakeError(source, f"key {names[i]} (frame {f}) would land {word} key "
                                    f"{names[i - 1]} (frame {frames[i - 1]}): keys must be in "
                                    "strictly increasing frames")


def key_checksum(item: dict) -> str:
    """CRC-32 of a key message's entries other than crc (canonical JSON), 8 hex digits."""
    body = json.dumps({k: item[k] for k in sorted(item) if k != "crc"}, separators=(",", ":"))
    return f"{zlib.crc32(body.encode()):08x}"


def encode_key(index: int, key: Key) -> bytes:
    """One key message (JSON bytes); its index is the key's id (``index`` when it has none)."""
    item = {"index": int(index if key.id is None else key.id), "frame": int(key.frame), "interpolation": str(key.interpolation),
            "ticks": [int(t) for t in np.asarray(key.ticks).tolist()],
            "ok": [bool(o) for o in np.asarray(key.ok).tolist()]}
    item["crc"] = key_checksum(item)
    return json.dumps(item).encode()


def _decode(data: bytes, k: int) -> Key:
    item = json.loads(data)
    if not isinstance(item, dict) or item.get("crc") != key_checksum(item):
        raise ValueError("checksum mismatch")
    ticks, ok = item["ticks"], item["ok"]
    if len(ticks) != k or len(ok) != k:
        raise ValueError(f"{len(ticks)} ticks / {len(ok)} ok, the take has {k} servos")
    if item["interpolation"] not in INTERPOLATIONS:
        raise ValueError(f"interpolation {item['interpolation']!r}")
    return Key(int(item["frame"]), np.asarray(ticks, np.int32), np.asarray(ok, bool),
               item["interpolation"], int(item["index"]))


def read_keys(path, k: int) -> Keys | None:
    """The keys of a shot of k servos (None for a take without a keys channel).

    Damaged key messages, and keys out of frame order, are skipped and listed in ``skipped``;
    a truncated tail keeps the keys before it.
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    from puppet.take.channels import channel_topic

    path = Path(path)
    channel, fps, keys, skipped, schemas, damaged = None, None, [], [], {}, []
    try:
        with open(path, "rb") as stream:
            for record in StreamReader(stream, skip_magic=False).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif (isinstance(record, Channel) and channel is None
                      and channel_topic(record.topic, schemas.get(record.schema_id)) == KEY_TOPIC):
                    channel = record.id
                    try:
                        fps = float(record.metadata["fps"])
                    except (KeyError, ValueError):
                        raise TakeError(path, f"keys channel: metadata fps "
                                              f"{record.metadata.get('fps')!r} is not a number") from None
                elif (isinstance(record, Message) and channel is not None
                      and record.channel_id == channel):
                    try:
                        key = _decode(record.data, k)
                    except (ValueError, KeyError, TypeError) as err:
                        skipped.append(f"key message {record.sequence}: {err}")
                        damaged.append((int(record.log_time), bytes(record.data)))
                        continue
                    if keys and key.frame <= keys[-1].frame:
                        skipped.append(f"key message {record.sequence}: frame {key.frame} not "
                                       f"after the previous key's {keys[-1].frame}")
                        damaged.append((int(record.log_time), bytes(record.data)))
                        continue
                    if any(other.id == key.id for other in keys):
                        skipped.append(f"key message {record.sequence}: id {key.id} taken by "
                                       "an earlier key")
                        damaged.append((int(record.log_time), bytes(record.data)))
                        continue
                    keys.append(key)
    except (McapError, EOFError, ValueError) as err:
        if channel is not None:
            skipped.append(f"the file ends damaged after {len(keys)} keys"
                           + (f" ({err})" if str(err) else ""))  # the record's own words follow
    except OSError as err:
        raise TakeError(path, f"cannot read keys: {err.strerror}") from err
    if channel is None:
        return None
    if not (fps and 0 < fps <= 1000):
        raise TakeError(path, f"keys channel: fps {fps} is not within (0, 1000]")
    return Keys(fps, keys, skipped, damaged)
