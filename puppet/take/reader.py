"""TakeReader: reads a take back, recovering what a crashed or truncated recording left."""

from __future__ import annotations

import json
import mmap
import struct
from array import array
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Iterator

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from puppet.bus.reading import Reading
from puppet.take import format as fmt
from puppet.take.errors import TakeError, TakeRigMismatch

MCAP_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
_KNOWN_OPCODES = {int(op) for op in Opcode}


class _ScanState:
    """What the record walk has seen so far."""

    def __init__(self):
        self.header: Header | None = None
        self.info: dict[str, str] | None = None
        self.texts: dict[str, str] = {}
        self.schemas: dict[int, Schema] = {}
        self.channel: Channel | None = None
        self.codec: fmt.ReadingCodec | None = None
        self.t_first: int | None = None
        self.last_t: int | None = None


@dataclass
class TakeMetadata:
    """What a take was recorded with.

    ids:              (k,) int64 servo ids, the order of every reading's ticks and ok.
    models:           servo id -> model name.
    rig_map_text:     the rig map TOML, verbatim.
    calibration_text: the calibration text, verbatim.
    rig_name:         the rig's name.
    format_version:   take format version (puppet.take.format.FORMAT_VERSION).
    created_unix_ns:  wall-clock time the recording started, ns since the Unix epoch.
    library:          the writer that made the file (MCAP header).
    """

    ids: np.ndarray
    models: dict[int, str]
    rig_map_text: str
    calibration_text: str
    rig_name: str
    format_version: int
    created_unix_ns: int
    library: str


def _parse(record_cls, body: bytes):
    """Parse one MCAP record body with the mcap package's record class."""
    return record_cls.read(ReadDataStream(BytesIO(body)))


class TakeReader:
    """Reads a take file; tolerant of a missing summary/footer and of a truncated or corrupt tail.

    Opening scans the file once (offsets of every reading, about 8 bytes each in memory).

    metadata:    TakeMetadata.
    truncated:   True when the file has no clean end (the writer did not close: crash, kill,
                 full disk) or ends in a partial or corrupt record; every complete reading
                 before that point is still read.
    recovery:    None for a cleanly closed take, else what was found, in words.
    valid_bytes: bytes of the file up to the end of the last good record.
    file_bytes:  size of the file.
    len(reader): number of readings; duration_s: last minus first timestamp, seconds.
    t_first_ns, t_last_ns: first and last timestamps (None for an empty take).
    """

    def __init__(self, path):
        self.path = Path(path)
        self.truncated = False
        self.recovery: str | None = None
        self._offsets = array("Q")
        self._payloads: list[bytes] | None = None
        self.t_first_ns: int | None = None
        self.t_last_ns: int | None = None
        with self._open_map() as mm:
            self.file_bytes = len(mm)
            self._scan(mm)

    # ---- opening and scanning ----
    def _open_map(self) -> mmap.mmap:
        try:
            f = open(self.path, "rb")
        except FileNotFoundError:
            raise TakeError(self.path, "no such take file") from None
        except IsADirectoryError:
            raise TakeError(self.path, "is a directory, not a take file") from None
        except OSError as e:
            raise TakeError(self.path, f"cannot open take file: {e.strerror}") from e
        with f:
            head = f.read(8)
            if len(head) == 0:
                raise TakeError(self.path, "empty file, not an MCAP take")
            if head != MCAP_MAGIC:
                raise TakeError(self.path, f"not an MCAP file (starts with {head!r})")
            return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)

    def _stop(self, reason: str) -> None:
        self.truncated = True
        self.recovery = reason

    def _scan(self, mm: mmap.mmap) -> None:
        """Walk the records once: header records, reading offsets, and where the file ends."""
        size = len(mm)
        pos = len(MCAP_MAGIC)
        s = _ScanState()
        clean_end = False
        while True:
            if pos == size:
                self._stop(f"no clean end after byte {pos} (the recording did not close)")
                break
            if pos + _RECORD_HEAD.size > size:
                self._stop(f"ends inside a record header at byte {pos} of {size}")
                break
            opcode, length = _RECORD_HEAD.unpack_from(mm, pos)
            body = pos + _RECORD_HEAD.size
            end = body + length
            if opcode not in _KNOWN_OPCODES:
                self._stop(f"corrupt record at byte {pos} (opcode 0x{opcode:02x})")
                break
            if end > size:
                self._stop(
                    f"ends inside a {Opcode(opcode).name} record at byte {pos} "
                    f"({end - size} of {length + 9} bytes missing)"
                )
                break
            if opcode == Opcode.DATA_END:
                clean_end = True
                pos = end
                break
            problem = None
            if opcode == Opcode.MESSAGE:
                if length < _MESSAGE_HEAD.size:
                    problem = f"{length} bytes"
                else:
                    channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack_from(mm, body)
                    start = body + _MESSAGE_HEAD.size
                    problem = self._message(s, channel_id, log_time, mm[start:end], start)
            elif opcode in (Opcode.HEADER, Opcode.METADATA, Opcode.SCHEMA, Opcode.CHANNEL,
                            Opcode.CHUNK):
                try:
                    problem = self._record(s, opcode, mm[body:end])
                except (struct.error, UnicodeDecodeError, ValueError, McapError, KeyError) as e:
                    problem = repr(e)
            if problem is not None:
                self._stop(f"corrupt {Opcode(opcode).name.lower()} record at byte {pos}: {problem}")
                break
            pos = end
        self.valid_bytes = pos
        if s.info is None or s.channel is None or len(s.texts) < 2:
            if self.truncated and (s.info is not None or s.header is not None):
                raise TakeError(
                    self.path,
                    f"take ends before its header records are complete ({self.recovery}): "
                    "no readings to recover",
                )
            raise self._not_puppet(s.info, s.header, s.texts)
        if clean_end:
            self.truncated = False
            self.recovery = None
        info = s.info
        ids = np.asarray(json.loads(info["ids"]), dtype=np.int64)
        ids.setflags(write=False)
        self.metadata = TakeMetadata(
            ids=ids,
            models={int(i): m for i, m in json.loads(info["models"]).items()},
            rig_map_text=s.texts[fmt.RIG_MAP_METADATA],
            calibration_text=s.texts[fmt.CALIBRATION_METADATA],
            rig_name=info.get("rig_name", ""),
            format_version=int(info["format_version"]),
            created_unix_ns=int(info.get("created_unix_ns", "0")),
            library=s.header.library if s.header is not None else "",
        )
        self._codec = fmt.ReadingCodec(len(ids))
        if self._payloads is not None:
            # A chunked take (rewritten by an MCAP tool): readings are held decoded-ready.
            self._offsets = array("Q", range(len(self._payloads)))
        if len(self._offsets):
            self.t_first_ns, self.t_last_ns = s.t_first, s.last_t

    def _record(self, s: "_ScanState", opcode: int, body: bytes) -> str | None:
        """Take in one non-message record; a problem in words, or None."""
        if opcode == Opcode.HEADER:
            s.header = _parse(Header, body)
        elif opcode == Opcode.METADATA:
            meta = _parse(Metadata, body)
            if meta.name == fmt.TAKE_METADATA:
                s.info = meta.metadata
                self._check_info(s.info)
            elif meta.name in (fmt.RIG_MAP_METADATA, fmt.CALIBRATION_METADATA):
                s.texts[meta.name] = meta.metadata.get("text", "")
        elif opcode == Opcode.SCHEMA:
            schema = _parse(Schema, body)
            s.schemas[schema.id] = schema
        elif opcode == Opcode.CHANNEL:
            self._channel(s, _parse(Channel, body))
        else:  # a chunk: takes are written unchunked, but MCAP tools may rewrite them chunked
            for rec in breakup_chunk(_parse(Chunk, body), validate_crc=True):
                if isinstance(rec, Schema):
                    s.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    self._channel(s, rec)
                elif isinstance(rec, Message):
                    if self._payloads is None:
                        self._payloads = []
                    problem = self._message(s, rec.channel_id, rec.log_time, rec.data, None)
                    if problem is not None:
                        return problem
        return None

    def _channel(self, s: "_ScanState", ch: Channel) -> None:
        if ch.topic == fmt.TOPIC:
            self._check_channel(ch, s.schemas)
            s.channel = ch

    def _message(self, s: "_ScanState", channel_id: int, log_time: int, payload, offset):
        """Take in one message; offset is its payload's file offset (None inside a chunk)."""
        if s.info is None or s.channel is None:
            raise self._not_puppet(s.info, s.header)
        if channel_id != s.channel.id:
            return None
        if s.codec is None:
            s.codec = fmt.ReadingCodec(int(s.info["servo_count"]))
        problem = s.codec.check(payload)
        if problem is not None:
            return problem
        if s.last_t is not None and log_time < s.last_t:
            return "time goes backwards"
        if s.t_first is None:
            s.t_first = log_time
        s.last_t = log_time
        if offset is None:
            self._payloads.append(bytes(payload))
        elif self._payloads is not None:
            self._payloads.append(bytes(payload))
        else:
            self._offsets.append(offset)
        return None

    def _not_puppet(self, info, header, texts=None) -> TakeError:
        library = header.library if header is not None else "unknown"
        if info is None:
            return TakeError(
                self.path, f"an MCAP file but not a puppet take (no {fmt.TAKE_METADATA} "
                f"metadata; written by {library!r})"
            )
        if texts is not None:
            missing = [m for m in (fmt.RIG_MAP_METADATA, fmt.CALIBRATION_METADATA) if m not in texts]
            if missing:
                return TakeError(self.path, f"not a complete puppet take: no {missing} metadata")
        return TakeError(self.path, f"not a puppet take: no {fmt.TOPIC} channel")

    def _check_info(self, info: dict[str, str]) -> None:
        try:
            version = int(info["format_version"])
        except (KeyError, ValueError):
            raise TakeError(
                self.path, f"{fmt.TAKE_METADATA} metadata has no valid format_version"
            ) from None
        if version != fmt.FORMAT_VERSION:
            newer = "newer" if version > fmt.FORMAT_VERSION else "older"
            raise TakeError(
                self.path,
                f"take format version {version} ({newer}); this puppet reads version "
                f"{fmt.FORMAT_VERSION}",
            )
        for field in ("ids", "models", "servo_count"):
            if field not in info:
                raise TakeError(self.path, f"{fmt.TAKE_METADATA} metadata lacks field {field!r}")
        try:
            ids = json.loads(info["ids"])
            json.loads(info["models"])
            k = int(info["servo_count"])
        except ValueError as e:
            raise TakeError(self.path, f"{fmt.TAKE_METADATA} metadata is malformed: {e}") from None
        if len(ids) != k:
            raise TakeError(
                self.path, f"{fmt.TAKE_METADATA} metadata: {len(ids)} ids but servo_count {k}"
            )

    def _check_channel(self, ch: Channel, schemas: dict[int, Schema]) -> None:
        schema = schemas.get(ch.schema_id)
        if schema is None:
            raise TakeError(self.path, f"channel {ch.topic} refers to missing schema {ch.schema_id}")
        if schema.name != fmt.SCHEMA_NAME or schema.encoding != fmt.SCHEMA_ENCODING:
            raise TakeError(
                self.path,
                f"channel {ch.topic} has schema {schema.name!r} ({schema.encoding}); "
                f"expected {fmt.SCHEMA_NAME!r} ({fmt.SCHEMA_ENCODING})",
            )
        if schema.data.decode("utf-8", "replace") != fmt.SCHEMA_TEXT:
            raise TakeError(self.path, f"schema {schema.name!r} differs from this puppet's version")
        if ch.message_encoding != fmt.MESSAGE_ENCODING:
            raise TakeError(
                self.path,
                f"channel {ch.topic} has message encoding {ch.message_encoding!r}, "
                f"expected {fmt.MESSAGE_ENCODING!r}",
            )

    # ---- reading ----
    def __len__(self) -> int:
        return len(self._offsets)

    @property
    def duration_s(self) -> float:
        """Seconds from the first to the last reading (0 for fewer than two)."""
        if len(self._offsets) < 2:
            return 0.0
        return (self.t_last_ns - self.t_first_ns) * 1e-9

    def _order(self, ids) -> np.ndarray | None:
        if ids is None:
            return None
        ids = np.asarray(ids)
        check_take_rig(self.metadata, ids=ids, path=self.path)
        where = {int(i): n for n, i in enumerate(self.metadata.ids)}
        return np.array([where[int(i)] for i in ids], dtype=np.int64)

    def readings(self, ids=None) -> Iterator[Reading]:
        """Every recovered reading in recorded order.

        ids: optional (k,) servo ids of the rig, a permutation of the take's ids; readings are
             then reordered to it (TakeRigMismatch when the sets differ).
        Yields Reading with fresh ticks (k,) int32 and ok (k,) bool arrays; ids is shared.
        """
        order = self._order(ids)
        out_ids = self.metadata.ids if order is None else np.asarray(ids)
        codec = self._codec
        with self._open_map() as mm:
            for off in self._offsets:
                if self._payloads is not None:
                    t_ns, ticks, ok = codec.decode(self._payloads[off])
                else:
                    t_ns, ticks, ok = codec.decode(mm[off : off + codec.size])
                if order is not None:
                    ticks, ok = ticks[order], ok[order]
                yield Reading(t_ns=t_ns, ids=out_ids, ticks=ticks, ok=ok)

    def __iter__(self) -> Iterator[Reading]:
        return self.readings()

    def arrays(self, ids=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All readings at once: t_ns (N,) int64, ticks (N, k) int32, ok (N, k) bool.

        ids: as in readings().
        """
        order = self._order(ids)
        k, size = self._codec.k, self._codec.size
        n = len(self._offsets)
        if self._payloads is not None:
            rows = np.frombuffer(b"".join(self._payloads), dtype=np.uint8).reshape(n, size)
        else:
            with self._open_map() as mm:
                raw = np.frombuffer(mm, dtype=np.uint8)
                idx = np.frombuffer(self._offsets, dtype=np.uint64).astype(np.int64)[:, None]
                rows = raw[idx + np.arange(size)] if n else np.zeros((0, size), np.uint8)
                del raw
        t_ns = rows[:, 4:12].copy().view("<i8").reshape(n)
        ticks = rows[:, 16 : 16 + 4 * k].copy().view("<i4").reshape(n, k).astype(np.int32)
        ok = rows[:, 20 + 4 * k : 20 + 5 * k] != 0
        if order is not None:
            ticks, ok = ticks[:, order], ok[:, order]
        return t_ns.astype(np.int64), ticks, ok

    def check_rig(self, ids, models: dict[int, str] | None = None, rig_name: str | None = None):
        """Raise TakeRigMismatch unless this take's servos are the rig's (see check_take_rig)."""
        check_take_rig(self.metadata, ids=ids, models=models, rig_name=rig_name, path=self.path)

    def __enter__(self) -> "TakeReader":
        return self

    def __exit__(self, *exc) -> None:
        pass


def check_take_rig(
    metadata: TakeMetadata,
    *,
    ids,
    models: dict[int, str] | None = None,
    rig_name: str | None = None,
    path=None,
) -> None:
    """Raise TakeRigMismatch ("take from another rig") unless the take's servos are the rig's.

    The servo id sets must be equal (order may differ: readings(ids=...) reorders), and where
    models are given, every servo's model must match. rig_name only makes the message clearer.
    """
    take_ids = [int(i) for i in metadata.ids]
    rig_ids = [int(i) for i in np.asarray(ids).ravel()]
    problems = []
    missing = sorted(set(rig_ids) - set(take_ids))
    extra = sorted(set(take_ids) - set(rig_ids))
    if missing:
        problems.append(f"servos {missing} of the rig are not in the take")
    if extra:
        problems.append(f"servos {extra} of the take are not in the rig")
    if models is not None:
        for i in sorted(set(take_ids) & set(rig_ids)):
            want, got = models.get(i), metadata.models.get(i)
            if want is not None and got is not None and want != got:
                problems.append(f"servo {i} is a {got} in the take but a {want} in the rig")
    if problems:
        rig = f"rig {rig_name!r}" if rig_name else "this rig"
        raise TakeRigMismatch(
            path if path is not None else "<take>",
            f"take from another rig: recorded on rig {metadata.rig_name!r} "
            f"(servos {take_ids}), played on {rig} (servos {rig_ids}): " + "; ".join(problems),
            take_ids=take_ids,
            rig_ids=rig_ids,
        )
