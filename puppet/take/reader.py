"""TakeReader: reads a take back, recovering every intact reading a damaged file still holds."""

from __future__ import annotations

import json
import mmap
import os
import stat
import struct
import zlib
from array import array
from collections import Counter
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Iterator

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from puppet.atomic import node_kind
from puppet.reading import Reading
from puppet.take import format as fmt
from puppet.take import sync
from puppet.take.channels import channel_topic, renamed
from puppet.take.sync import SoundRef
from puppet.timecode import StartTimecode
from puppet.take.errors import TakeError, TakeRigMismatch
from puppet.take.layers import LAYER_METADATA, LayerRef
from puppet.take.playback import gap_note

MCAP_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
_KNOWN_OPCODES = {int(op) for op in Opcode}
_HEADER_OPCODES = (Opcode.HEADER, Opcode.METADATA, Opcode.SCHEMA, Opcode.CHANNEL)
# Records a valid MCAP data section may hold that a take does not need.
_QUIET_OPCODES = (Opcode.ATTACHMENT, Opcode.MESSAGE_INDEX)
_RESYNC_WINDOW = 1 << 20  # bytes searched byte by byte for a header record after damage
_PARSE_ERRORS = (struct.error, UnicodeDecodeError, ValueError, McapError, KeyError,
                 IndexError, OverflowError, MemoryError)


@dataclass
class RecoveryReport:
    """What reading a take found damaged, and what it did about it.

    skipped: reason -> records skipped for it ("checksum mismatch", "malformed reading",
             "log time disagrees", "out of order", "unknown channel", "corrupt record");
             every other reading is still read.
    details: the first few skips, in words, with their byte offsets.
    notes:   damage that lost no reading (a corrupt rig map or calibration record, a damaged
             schema or channel record, gaps that playback cuts), in words.
    end:     why the file has no clean end (crash, kill, full disk, a damaged tail), or None.
    """

    skipped: Counter = field(default_factory=Counter)
    details: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    end: str | None = None

    MAX_DETAILS = 3

    def skip(self, reason: str, detail: str) -> None:
        self.skipped[reason] += 1
        if len(self.details) < self.MAX_DETAILS:
            self.details.append(detail)

    @property
    def skipped_count(self) -> int:
        return sum(self.skipped.values())

    @property
    def clean(self) -> bool:
        """True when nothing was found wrong."""
        return not self.skipped and not self.notes and self.end is None

    def text(self) -> str | None:
        """Everything found, in one line of words (None when clean)."""
        if self.clean:
            return None
        parts = []
        if self.skipped:
            counts = ", ".join(f"{n} {reason}" for reason, n in sorted(self.skipped.items()))
            more = "" if self.skipped_count <= len(self.details) else ", ..."
            parts.append(f"skipped {self.skipped_count} damaged record(s) ({counts}): "
                         + "; ".join(self.details) + more)
        parts += self.notes
        if self.end is not None:
            parts.append(self.end)
        return "; ".join(parts)


class _ScanState:
    """What the record walk has seen so far."""

    def __init__(self):
        self.header: Header | None = None
        self.info: dict[str, str] | None = None
        self.info_damaged: str | None = None
        self.texts: dict[str, str] = {}
        self.schemas: dict[int, Schema] = {}
        self.channel: Channel | None = None
        self.channel_id: int | None = None
        self.other_channels: set[int] = set()  # channels of other topics (e.g. /puppet/markers)
        self.unknown_channels: set[int] = set()  # of them, those neither name nor schema places
        self.version: int | None = None
        self.codec: fmt.ReadingCodec | None = None
        self.msg_len: int | None = None  # MCAP body length of one reading's message record
        self.t_first: int | None = None
        self.last_t: int | None = None
        self.orphans = 0  # reading records met before the take metadata could be read
        self.sync: dict[str, dict[str, str]] = {}  # the sound and timecode records, as read


@dataclass
class TakeMetadata:
    """What a take was recorded with.

    ids:              (k,) int64 servo ids, the order of every reading's ticks and ok.
    models:           servo id -> model name (empty if the metadata record was damaged).
    rig_map_text:     the rig map TOML, verbatim ("" if its record was damaged).
    calibration_text: the calibration text, verbatim ("" if its record was damaged).
    rig_name:         the rig's name.
    format_version:   take format version (puppet.take.format.READABLE_VERSIONS).
    created_unix_ns:  wall-clock time the recording started, ns since the Unix epoch.
    library:          the writer that made the file (MCAP header).
    sound:            the sound the take was performed to (``puppet.take.sync.SoundRef``), or
                      None (none, a take older than sound, or a damaged record: in the report).
    timecode:         the start timecode (``puppet.timecode.StartTimecode``) or None (likewise).
    layer:            what the take is a layer of (``puppet.take.layers.LayerRef``), or None
                      (a plain take; a damaged record: in the report, the take plays alone).
    """

    ids: np.ndarray
    models: dict[int, str]
    rig_map_text: str
    calibration_text: str
    rig_name: str
    format_version: int
    created_unix_ns: int
    library: str
    sound: SoundRef | None = None
    timecode: StartTimecode | None = None
    layer: object | None = None


def _parse(record_cls, body: bytes):
    """Parse one MCAP record body with the mcap package's record class."""
    return record_cls.read(ReadDataStream(BytesIO(body)))


def _written_length(opcode: int, body: bytes) -> int | None:
    """Bytes a metadata, schema or channel record's fields take, as written again from what
    parses of ``body`` (None for another record, or one that does not parse)."""
    from mcap.data_stream import RecordBuilder

    cls = {Opcode.METADATA: Metadata, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel}.get(opcode)
    if cls is None:
        return None
    try:
        builder = RecordBuilder()
        _parse(cls, body).write(builder)
    except _PARSE_ERRORS:
        return None
    return len(builder.end()) - _RECORD_HEAD.size


def _schema_version(schema: Schema | None) -> int | None:
    """The take format version whose reading schema this is, or None."""
    if schema is None or schema.name != fmt.SCHEMA_NAME:
        return None
    text = schema.data.decode("utf-8", "replace")
    return next((v for v, t in fmt.SCHEMA_TEXTS.items() if t == text), None)


def _column(rows: np.ndarray, start: int, dtype: str) -> np.ndarray:
    """(n,) values of one fixed-offset field of (n, record) byte rows (a copy)."""
    width = np.dtype(dtype).itemsize
    return np.ascontiguousarray(rows[:, start : start + width]).view(dtype)[:, 0]


def _opname(opcode: int) -> str:
    return Opcode(opcode).name.lower() if opcode in _KNOWN_OPCODES else f"0x{opcode:02x}"


class TakeReader:
    """Reads a take file, recovering every intact reading of a damaged one.

    Opening scans the file once (offset and time of every reading, about 16 bytes each in
    memory). Damage is skipped, never replayed: a record that cannot be read is stepped over
    (every reading has the same size, so the next one is found again), a reading whose checksum
    (format 2), layout, or timestamp (against the MCAP log time, and in order) is wrong is
    skipped, and a damaged rig map or calibration record is reported and left out.

    metadata:    TakeMetadata.
    report:      RecoveryReport: counts of what was skipped and why, notes, how the file ends.
    recovery:    None for an undamaged, cleanly closed take, else report.text().
    truncated:   True when the file has no clean end (the writer did not close: crash, kill,
                 full disk) or ends in damage; every intact reading before that is still read.
    valid_bytes: bytes of the file up to the end of the last record read.
    file_bytes:  size of the file.
    len(reader): number of readings; duration_s: last minus first timestamp, seconds.
    t_first_ns, t_last_ns: first and last timestamps (None for an empty take).
    """

    def __init__(self, path):
        self.path = Path(path)
        self.truncated = False
        self.topics: set[str] = set()  # channels beside the readings (/puppet/markers, /puppet/keys)
        self.report = RecoveryReport()
        self._offsets = array("Q")
        self._times = array("q")
        self._payloads: list[bytes] | None = None
        self.t_first_ns: int | None = None
        self.t_last_ns: int | None = None
        with self._open_map(first=True) as mm:
            self.file_bytes = len(mm)
            self._scan(mm)
        self._keys = self._read_keys()
        if self._keys is None:
            self._note_gaps()  # a shot's keys are spaced by the animator: nothing is cut
        self.recovery: str | None = self.report.text()

    # ---- opening and scanning ----
    def _open_map(self, first: bool = False) -> mmap.mmap:
        """The file mapped read-only; first: check (and report) its magic bytes. A FIFO, device
        or socket is refused unopened (opening a FIFO blocks until a writer comes)."""
        try:
            mode = os.stat(self.path).st_mode
        except OSError:
            mode = None  # open() below names what is wrong
        if mode is not None and not stat.S_ISDIR(mode) and node_kind(mode) is not None:
            raise TakeError(self.path, f"is {node_kind(mode)}, not a take file (only regular "
                                       "files are read)")
        try:
            f = open(self.path, "rb")
        except FileNotFoundError:
            raise TakeError(self.path, "no such take file") from None
        except IsADirectoryError:
            raise TakeError(self.path, "is a directory, not a take file") from None
        except OSError as e:
            raise TakeError(self.path, f"cannot open take file: {e.strerror}") from e
        with f:
            head = f.read(8 + _RECORD_HEAD.size)
            if not first:
                return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
            if len(head) == 0:
                raise TakeError(self.path, "empty file, not an MCAP take")
            if head[:8] != MCAP_MAGIC:
                # One or two damaged bytes of the magic, followed by a header record: a take.
                wrong = sum(a != b for a, b in zip(head[:8], MCAP_MAGIC))
                if len(head) < 17 or wrong > 2 or head[8] != Opcode.HEADER:
                    raise TakeError(self.path, f"not an MCAP file (starts with {head[:8]!r})")
                self.report.notes.append(f"the file's magic bytes are damaged ({head[:8]!r})")
            return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)

    def _scan(self, mm: mmap.mmap) -> None:
        """Walk the records once: header records, reading offsets, and where the file ends."""
        size = len(mm)
        pos = len(MCAP_MAGIC)
        s = _ScanState()
        clean_end = False
        report = self.report
        while True:
            if pos == size:
                report.end = f"no clean end after byte {pos} (the recording did not close)"
                break
            if pos + _RECORD_HEAD.size > size:
                report.end = f"ends inside a record header at byte {pos} of {size}"
                break
            opcode, length = _RECORD_HEAD.unpack_from(mm, pos)
            body = pos + _RECORD_HEAD.size
            end = body + length
            damage = None  # (reason, what is wrong at pos, trusted end or None)
            cut = False  # the damage is the file's end cutting a record
            if opcode not in _KNOWN_OPCODES:
                damage = ("corrupt record", f"corrupt record at byte {pos} (opcode 0x{opcode:02x})",
                          None)
            elif (opcode == Opcode.MESSAGE and s.msg_len is not None and length != s.msg_len
                  and not self._other_channel_message(mm, s, body, end)):
                damage = ("corrupt record", f"corrupt message record at byte {pos} "
                          f"({length + 9} bytes, a reading has {s.msg_len + 9})", None)
            elif end > size:
                cut = True
                damage = ("corrupt record", f"ends inside a {_opname(opcode)} record at byte {pos} "
                          f"({end - size} of {length + 9} bytes missing)", None)
            elif opcode == Opcode.DATA_END:
                if length == 4:
                    clean_end = True
                    pos = end
                    break
                damage = ("corrupt record", f"corrupt data end record at byte {pos}", None)
            elif opcode == Opcode.MESSAGE:
                if s.codec is not None and s.channel_id is not None and self._payloads is None:
                    after = self._bulk(mm, s, pos)  # the common case: a run of good readings
                    if after > pos:
                        pos = after
                        continue
                damage = self._message_record(mm, s, pos, body, end)
            elif opcode in _HEADER_OPCODES or opcode == Opcode.CHUNK:
                try:
                    problem = self._record(s, opcode, mm[body:end])
                except _PARSE_ERRORS as e:
                    problem = f"{type(e).__name__}: {e}"
                if problem is not None:
                    damage = ("corrupt record", f"damaged {_opname(opcode)} record at byte {pos} "
                              f"({problem})", end)
                else:
                    exact = _written_length(opcode, mm[body:end])
                    if exact is not None and exact != length and self._boundary(mm, s, body + exact):
                        # its length field is damaged (a take's writer adds nothing after a
                        # record's fields): the record ends where its content does, and the
                        # reading after it is read, not swallowed
                        report.notes.append(f"{_opname(opcode)} record at byte {pos}: its length "
                                            f"field says {length} bytes, its content {exact}")
                        pos = body + exact
                        continue
            elif opcode in _QUIET_OPCODES:
                pass
            else:
                damage = ("corrupt record", f"unexpected {_opname(opcode)} record at byte {pos}",
                          end)
            if damage is None:
                pos = end
                continue
            reason, what, trusted_end = damage
            if trusted_end is not None and self._boundary(mm, s, trusted_end):
                report.skip(reason, what)
                pos = trusted_end
                continue
            found = self._resync(mm, s, pos + 1)
            if found is None:
                report.end = what if cut else f"{what}; nothing readable after it"
                break
            report.skip(reason, f"{what}; resumed at byte {found}")
            pos = found
        self.valid_bytes = pos
        self.truncated = not clean_end
        self._finish(s)

    def _finish(self, s: "_ScanState") -> None:
        """Check the header records are usable and build the metadata."""
        if s.info is None and s.channel is not None:
            self._fallback_info(s)
        if s.info is None or s.channel_id is None:
            if s.info_damaged is not None:
                raise TakeError(self.path, f"the take metadata record is damaged "
                                f"({s.info_damaged}) and no servo ids can be recovered")
            if self.truncated and (s.info is not None or s.header is not None):
                raise TakeError(
                    self.path,
                    f"take ends before its header records are complete ({self.report.text()}): "
                    "no readings to recover",
                )
            raise self._not_puppet(s.info, s.header)
        info = s.info
        texts = {}
        for name, what in ((fmt.RIG_MAP_METADATA, "rig map"),
                           (fmt.CALIBRATION_METADATA, "calibration")):
            text = s.texts.get(name)
            crc = info.get(f"{name.split('.')[-1]}_crc32")
            if text is None:
                self.report.notes.append(f"no {what} metadata (its record is damaged or missing)")
                text = ""
            elif crc is not None and fmt.text_checksum(text) != crc:
                self.report.notes.append(
                    f"the {what} metadata is damaged (checksum mismatch); it is left out")
                text = ""
            texts[name] = text
        ids = np.asarray(json.loads(info["ids"]), dtype=np.int64)
        ids.setflags(write=False)
        try:
            created = int(info.get("created_unix_ns", "0"))
        except ValueError:
            created = 0
        self.metadata = TakeMetadata(
            ids=ids,
            models={int(i): m for i, m in json.loads(info["models"]).items()},
            rig_map_text=texts[fmt.RIG_MAP_METADATA],
            calibration_text=texts[fmt.CALIBRATION_METADATA],
            rig_name=info.get("rig_name", ""),
            format_version=s.version,
            created_unix_ns=created,
            library=s.header.library if s.header is not None else "",
            sound=self._sync_record(s, sync.SOUND_METADATA, "sound", sync.SoundRef.from_metadata),
            timecode=self._sync_record(s, sync.TIMECODE_METADATA, "timecode",
                                       sync.timecode_from_metadata),
            layer=self._sync_record(s, LAYER_METADATA, "layer", LayerRef.from_metadata),
        )
        if s.orphans:
            self.report.skip("corrupt record", f"{s.orphans} reading record(s) before the take "
                             "metadata could be read")
        self._codec = s.codec if s.codec is not None else fmt.ReadingCodec(len(ids), s.version)
        if self._payloads is not None:
            # A chunked take (rewritten by an MCAP tool): readings are held decoded-ready.
            self._offsets = array("Q", range(len(self._payloads)))
        if len(self._offsets):
            self.t_first_ns, self.t_last_ns = s.t_first, s.last_t

    def _sync_record(self, s: "_ScanState", name: str, what: str, parse):
        """The value of an optional sync record (puppet.take.sync), None when absent; a damaged
        one is reported and left out (the take plays without it)."""
        info = s.sync.get(name)
        if info is None:
            return None
        try:
            return parse(info)
        except (ValueError, KeyError) as err:
            self.report.notes.append(f"the {what} metadata is damaged ({err}); it is left out")
            return None

    def _note_gaps(self) -> None:
        """Report gaps between readings that playback cuts (puppet.take.playback.gap_note)."""
        if len(self._times) < 2:
            return
        note = gap_note(np.frombuffer(self._times, dtype=np.int64))
        if note is not None:
            self.report.notes.append(note)

    def _bulk(self, mm: mmap.mmap, s: "_ScanState", pos: int) -> int:
        """Take in the run of back-to-back good readings starting at pos, checked all at once;
        the position after the run (pos when the first one is not good: checked one by one)."""
        record = _RECORD_HEAD.size + s.msg_len
        n = (len(mm) - pos) // record
        if n < 2:
            return pos
        k, codec = s.codec.k, s.codec
        p0 = _RECORD_HEAD.size + _MESSAGE_HEAD.size  # payload offset inside a record
        rows = np.frombuffer(mm, dtype=np.uint8, count=n * record, offset=pos).reshape(n, record)
        t_ns = _column(rows, p0 + 4, "<i8")
        good = ((rows[:, 0] == Opcode.MESSAGE) & (_column(rows, 1, "<u8") == s.msg_len)
                & (_column(rows, 9, "<u2") == s.channel_id)
                & (_column(rows, 15, "<u8").astype(np.int64) == t_ns)
                & (_column(rows, p0, "<u4") == 0x0100)  # the CDR_LE encapsulation header
                & (_column(rows, p0 + 12, "<u4") == k)
                & (_column(rows, p0 + 16 + 4 * k, "<u4") == k))
        ordered = np.diff(t_ns, prepend=t_ns[:1] if s.last_t is None else s.last_t) >= 0
        bad = np.flatnonzero(~(good & ordered))
        m = int(bad[0]) if bad.size else n
        if codec.crc_at is not None and m:
            stored = _column(rows, p0 + codec.crc_at, "<u4")[:m].tolist()
            with memoryview(mm) as view:
                for i in range(m):
                    at = pos + i * record + p0
                    if zlib.crc32(view[at : at + codec.crc_at]) != stored[i]:
                        m = i
                        break
        del rows
        if m == 0:
            return pos
        offsets = pos + p0 + record * np.arange(m, dtype=np.int64)
        self._offsets.frombytes(offsets.astype(np.uint64).tobytes())
        self._times.frombytes(t_ns[:m].astype(np.int64).tobytes())
        if s.t_first is None:
            s.t_first = int(t_ns[0])
        s.last_t = int(t_ns[m - 1])
        return pos + m * record

    def _boundary(self, mm: mmap.mmap, s: "_ScanState", q: int) -> bool:
        """True when a record may start at q (or the file ends there): a length can be trusted."""
        size = len(mm)
        if q >= size - _RECORD_HEAD.size:
            return q <= size
        opcode, length = _RECORD_HEAD.unpack_from(mm, q)
        if opcode not in _KNOWN_OPCODES:
            return False
        if opcode == Opcode.MESSAGE and s.msg_len is not None and length != s.msg_len:
            body = q + _RECORD_HEAD.size  # a message of another topic (a marker) may follow
            return (body + 2 <= size and struct.unpack_from("<H", mm, body)[0] in s.other_channels
                    and body + length <= size)
        return q + _RECORD_HEAD.size + length <= size

    def _message_at(self, mm: mmap.mmap, s: "_ScanState", q: int) -> bool:
        """True when a reading whose payload checks out starts at q."""
        if q + _RECORD_HEAD.size + s.msg_len > len(mm):
            return False
        channel_id = struct.unpack_from("<H", mm, q + _RECORD_HEAD.size)[0]
        if s.channel_id is not None and channel_id != s.channel_id:
            return False
        start = q + _RECORD_HEAD.size + _MESSAGE_HEAD.size
        return s.codec.check(mm[start : start + s.codec.size]) is None

    def _resync(self, mm: mmap.mmap, s: "_ScanState", start: int) -> int | None:
        """The first position at or after start where a trustworthy record begins, or None.

        A reading is found by its fixed record head (opcode, length) and a payload that checks
        out; a data end record by its fixed form; before the readings, header records are
        searched byte by byte (within _RESYNC_WINDOW) and must parse and be followed by a
        record boundary.
        """
        best = None
        if s.msg_len is not None:
            signature = _RECORD_HEAD.pack(Opcode.MESSAGE, s.msg_len)
            q = mm.find(signature, start)
            while q != -1 and not self._message_at(mm, s, q):
                q = mm.find(signature, q + 1)
            best = None if q == -1 else q
            stop = best if best is not None else len(mm)
            q = mm.find(_RECORD_HEAD.pack(Opcode.DATA_END, 4), start, stop)
            if q != -1 and q + 13 <= len(mm):
                best = q
        limit = min(best if best is not None else len(mm), start + _RESYNC_WINDOW)
        if s.channel_id is None:
            for q in range(start, limit - _RECORD_HEAD.size):
                opcode = mm[q]
                if opcode not in (Opcode.METADATA, Opcode.SCHEMA, Opcode.CHANNEL):
                    continue
                length = _RECORD_HEAD.unpack_from(mm, q)[1]
                end = q + _RECORD_HEAD.size + length
                if end > len(mm) or not self._boundary(mm, s, end):
                    continue
                cls = {Opcode.METADATA: Metadata, Opcode.SCHEMA: Schema,
                       Opcode.CHANNEL: Channel}[opcode]
                try:
                    _parse(cls, mm[q + _RECORD_HEAD.size : end])
                except _PARSE_ERRORS:
                    continue
                return q
        return best

    def _other_channel_message(self, mm: mmap.mmap, s: "_ScanState", body: int, end: int) -> bool:
        """A whole message record on a channel of another topic (a marker): not a damaged reading."""
        if end > len(mm) or end - body < _MESSAGE_HEAD.size:
            return False
        channel_id = struct.unpack_from("<H", mm, body)[0]
        return channel_id in s.other_channels and self._boundary(mm, s, end)

    def _message_record(self, mm, s: "_ScanState", pos: int, body: int, end: int):
        """Take in one message record; None, or (reason, what is wrong, trusted end)."""
        if end - body < _MESSAGE_HEAD.size:
            return ("corrupt record", f"corrupt message record at byte {pos} "
                    f"({end - body} bytes)", None)
        if s.codec is None:
            if s.info is None and s.channel is not None:
                self._fallback_info(s)
            self._prepare_codec(s)
        if s.codec is None:
            s.orphans += 1
            return None
        channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack_from(mm, body)
        start = body + _MESSAGE_HEAD.size
        problem = self._take_message(s, channel_id, log_time, mm[start:end])
        if problem is None or problem == "other channel":
            if problem is None and self._payloads is None:
                self._offsets.append(start)
            return None
        reason, detail = problem
        return reason, f"reading at byte {pos}: {detail}", end

    def _take_message(self, s: "_ScanState", channel_id: int, log_time: int, payload):
        """Check one message: None (a good reading, counted), "other channel", or (reason, detail)."""
        if channel_id != s.channel_id:
            content = (s.channel_id is None and len(payload) == s.codec.size
                       and s.codec.version >= 2 and s.codec.check(payload) is None)
            if (channel_id in s.other_channels and not (content and channel_id in s.unknown_channels)
                    or len(payload) != s.codec.size):
                return "other channel"  # a message a tool added to the take: not a reading
            if content:
                s.other_channels.discard(channel_id)
                s.channel_id = channel_id
                self.report.notes.append(
                    "the readings' channel record is damaged; readings recognised by checksum")
            else:
                return "unknown channel", f"channel id {channel_id}, readings are on {s.channel_id}"
        problem = s.codec.check(payload)
        if problem is not None:
            return problem
        t_ns = s.codec.t_ns_of(payload)
        if t_ns != log_time:
            return "log time disagrees", f"log time {log_time} ns, the reading says {t_ns} ns"
        if s.last_t is not None and t_ns < s.last_t:
            return "out of order", f"t_ns {t_ns} is before the previous reading's {s.last_t}"
        if s.t_first is None:
            s.t_first = t_ns
        s.last_t = t_ns
        self._times.append(t_ns)
        if self._payloads is not None:
            self._payloads.append(bytes(payload))
        return None

    def _record(self, s: "_ScanState", opcode: int, body: bytes) -> str | None:
        """Take in one non-message record; a problem in words, or None."""
        if opcode == Opcode.HEADER:
            s.header = _parse(Header, body)
        elif opcode == Opcode.METADATA:
            meta = _parse(Metadata, body)
            if meta.name == fmt.TAKE_METADATA:
                problem = self._check_info(meta.metadata)
                if problem is not None:
                    s.info_damaged = problem
                    return problem
                s.info = meta.metadata
                s.version = int(s.info["format_version"])
                self._prepare_codec(s)
            elif meta.name in (fmt.RIG_MAP_METADATA, fmt.CALIBRATION_METADATA):
                s.texts[meta.name] = meta.metadata.get("text", "")
            elif meta.name in (sync.SOUND_METADATA, sync.TIMECODE_METADATA, LAYER_METADATA):
                s.sync[meta.name] = meta.metadata
        elif opcode == Opcode.SCHEMA:
            schema = _parse(Schema, body)
            s.schemas[schema.id] = schema
        elif opcode == Opcode.CHANNEL:
            self._channel(s, _parse(Channel, body))
        else:  # a chunk: takes are written unchunked, but MCAP tools may rewrite them chunked
            records = list(breakup_chunk(_parse(Chunk, body), validate_crc=True))
            for rec in records:
                if isinstance(rec, Schema):
                    s.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    self._channel(s, rec)
                elif isinstance(rec, Message):
                    if s.codec is None:
                        raise self._not_puppet(s.info, s.header)
                    if self._payloads is None:
                        self._payloads = []
                    problem = self._take_message(s, rec.channel_id, rec.log_time, rec.data)
                    if problem is not None and problem != "other channel":
                        self.report.skip(problem[0], f"reading in a chunk: {problem[1]}")
        return None

    def _prepare_codec(self, s: "_ScanState") -> None:
        if s.codec is None and s.info is not None:
            s.codec = fmt.ReadingCodec(int(s.info["servo_count"]), s.version)
            s.msg_len = _MESSAGE_HEAD.size + s.codec.size

    def _channel(self, s: "_ScanState", ch: Channel) -> None:
        topic = channel_topic(ch.topic, s.schemas.get(ch.schema_id))
        if topic is not None and topic != ch.topic:
            self.report.notes.append(renamed(ch.topic, topic))
        if topic != fmt.TOPIC:
            s.other_channels.add(ch.id)
            if topic is None:
                s.unknown_channels.add(ch.id)
            self.topics.add(topic or ch.topic)
            return
        version = s.version
        if version is None:  # the take metadata is damaged: the schema tells the version
            version = _schema_version(s.schemas.get(ch.schema_id))
        problem = self._check_channel(ch, s.schemas, version)
        if problem is not None:
            if version is None or version < 2:
                raise TakeError(self.path, problem)
            self.report.notes.append(f"{problem} (damaged; the readings' checksums are used)")
        s.channel = ch
        s.channel_id = ch.id

    def _fallback_info(self, s: "_ScanState") -> None:
        """Rebuild the take metadata from the channel record when its own record is damaged."""
        try:
            ids = [int(i) for i in s.channel.metadata["ids"].split(",")]
        except (KeyError, ValueError):
            return
        version = _schema_version(s.schemas.get(s.channel.schema_id))
        if version is None:
            return
        s.info = {"format_version": str(version), "ids": json.dumps(ids), "models": "{}",
                  "servo_count": str(len(ids)), "rig_name": ""}
        s.version = version
        damage = f"damaged ({s.info_damaged})" if s.info_damaged else "damaged or missing"
        self.report.notes.append(
            f"the take metadata record is {damage}; servo ids taken from the channel record, "
            "servo models and rig name unknown, rig map and calibration unchecked")

    def _not_puppet(self, info, header) -> TakeError:
        library = header.library if header is not None else "unknown"
        if info is None:
            return TakeError(
                self.path, f"an MCAP file but not a puppet take (no {fmt.TAKE_METADATA} "
                f"metadata; written by {library!r})"
            )
        return TakeError(self.path, f"not a puppet take: no {fmt.TOPIC} channel")

    def _check_info(self, info: dict[str, str]) -> str | None:
        """None when the take metadata is usable; its damage in words (format 2 checksum);
        TakeError when it is well formed but not readable here."""
        crc = info.get("crc32")
        if crc is not None and fmt.info_checksum(info) != crc:
            return "checksum mismatch"
        try:
            version = int(info["format_version"])
        except (KeyError, ValueError):
            raise TakeError(
                self.path, f"{fmt.TAKE_METADATA} metadata has no valid format_version"
            ) from None
        if version not in fmt.READABLE_VERSIONS:
            newest = max(fmt.READABLE_VERSIONS)
            newer = "newer" if version > newest else "older"
            raise TakeError(
                self.path,
                f"take format version {version} ({newer}); this puppet reads versions "
                f"{', '.join(map(str, fmt.READABLE_VERSIONS[:-1]))} and {fmt.READABLE_VERSIONS[-1]}",
            )
        if version >= 2 and crc is None:
            return "no crc32 entry"
        for name in ("ids", "models", "servo_count"):
            if name not in info:
                raise TakeError(self.path, f"{fmt.TAKE_METADATA} metadata lacks field {name!r}")
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
        return None

    def _check_channel(self, ch: Channel, schemas: dict[int, Schema], version) -> str | None:
        """None when the readings' channel and schema are this format's; else what differs."""
        schema = schemas.get(ch.schema_id)
        if schema is None:
            return f"channel {ch.topic} refers to missing schema {ch.schema_id}"
        if schema.name != fmt.SCHEMA_NAME or schema.encoding != fmt.SCHEMA_ENCODING:
            return (f"channel {ch.topic} has schema {schema.name!r} ({schema.encoding}); "
                    f"expected {fmt.SCHEMA_NAME!r} ({fmt.SCHEMA_ENCODING})")
        expected = fmt.SCHEMA_TEXTS.get(version if version is not None else 1)
        if schema.data.decode("utf-8", "replace") != expected:
            return f"schema {schema.name!r} differs from this puppet's version"
        if ch.message_encoding != fmt.MESSAGE_ENCODING:
            return (f"channel {ch.topic} has message encoding {ch.message_encoding!r}, "
                    f"expected {fmt.MESSAGE_ENCODING!r}")
        return None

    # ---- reading ----
    def __len__(self) -> int:
        return len(self._offsets)

    def timestamps(self) -> np.ndarray:
        """(N,) int64 t_ns of every reading, in order (a copy)."""
        return np.array(self._times, dtype=np.int64)

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
        Yields Reading with fresh ticks (k,) int32 and ok (k,) bool arrays (and late (k,) bool
        from take format 3 on; None before: the reason a read failed was not kept); ids is shared.
        """
        order = self._order(ids)
        out_ids = self.metadata.ids if order is None else np.asarray(ids)
        codec = self._codec
        with self._open_map() as mm:
            for off in self._offsets:
                if self._payloads is not None:
                    t_ns, ticks, ok, late = codec.decode(self._payloads[off])
                else:
                    t_ns, ticks, ok, late = codec.decode(mm[off : off + codec.size])
                if order is not None:
                    ticks, ok = ticks[order], ok[order]
                    late = None if late is None else late[order]
                yield Reading(t_ns=t_ns, ids=out_ids, ticks=ticks, ok=ok, late=late)

    def __iter__(self) -> Iterator[Reading]:
        return self.readings()

    def arrays(self, ids=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All readings at once: t_ns (N,) int64, ticks (N, k) int32, ok (N, k) bool.

        ids: as in readings(). ``late(ids)``: which of the servos not ok were only late.
        """
        t_ns, ticks, ok, _ = self._arrays(ids)
        return t_ns, ticks, ok

    def late(self, ids=None) -> np.ndarray | None:
        """(N, k) bool: True where a servo's value is held only because its reply came late
        (``Reading.late``); None for a take of format 1 or 2 (the reason was not kept).
        ids: as in readings()."""
        return self._arrays(ids)[3]

    def _arrays(self, ids=None):
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
        ok, late = self._codec.ok_late(rows[:, 20 + 4 * k : 20 + 5 * k])
        if order is not None:
            ticks, ok = ticks[:, order], ok[:, order]
            late = None if late is None else late[:, order]
        return t_ns.astype(np.int64), ticks, ok, late

    def keys(self):
        """The shot's keys (``puppet.take.keys.Keys``, in the take's ids order), or None for a
        take without a keys channel; damaged keys it skipped are in ``recovery``."""
        return self._keys

    def _read_keys(self):
        from puppet.take.keys import KEY_TOPIC, read_keys

        if KEY_TOPIC not in self.topics:
            return None
        keys = read_keys(self.path, len(self.metadata.ids))
        if keys.skipped:
            self.report.notes.append(f"skipped {len(keys.skipped)} damaged key(s): "
                                     + "; ".join(keys.skipped[:5]))
        return keys

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
