"""TakeWriter: crash-safe, append-only recording of raw servo readings into an MCAP take."""

from __future__ import annotations

import errno
import json
import os
import time
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType, IndexType, Writer

import puppet
from puppet.reading import Reading
from puppet.take import format as fmt
from puppet.take import sync
from puppet.take.errors import TakeError


class TakeWriter:
    """Records Readings of one rig into an MCAP take file.

    Crash safety: messages are written unchunked and every write() hands its record to the
    operating system before returning, so a process killed with SIGKILL leaves every reading
    whose write() returned. fsync (for power loss) runs at most every fsync_interval_s seconds,
    inside write(), and at close(); call write() from a sink thread, not the bus thread.
    A failed write (a full disk) raises TakeError naming the take and ends the recording;
    every reading written before it stays readable.

    path:             take file to create (.mcap); an existing file is an error unless overwrite.
    ids:              (k,) int servo ids, in the order of Reading.ticks.
    models:           servo id -> model name (e.g. "XL430-W250"), one per id.
    rig_map_text:     the rig map TOML the take is recorded with (stored verbatim).
    calibration_text: the calibration text the take is recorded with (stored verbatim).
    rig_name:         a name for the rig.
    fsync_interval_s: seconds between fsyncs; None never fsyncs before close().
    overwrite:        replace an existing file.
    sound:            the sound the take is performed to (``puppet.take.sync.SoundRef``: its
                      hash, file, offset at the take's time 0, rate), or None.
    timecode:         the take's start timecode (``puppet.timecode.StartTimecode``), or None.
    layer:            what the take is a layer of (``puppet.take.layers.LayerRef``), or None.
    """

    def __init__(
        self,
        path,
        *,
        ids,
        models: dict[int, str],
        rig_map_text: str,
        calibration_text: str,
        rig_name: str,
        fsync_interval_s: float | None = 1.0,
        overwrite: bool = False,
        sound=None,
        timecode=None,
        layer=None,
    ):
        self.path = Path(path)
        self.ids = np.asarray(ids)
        if self.ids.ndim != 1 or self.ids.size == 0 or not np.issubdtype(self.ids.dtype, np.integer):
            raise TakeError(self.path, f"ids must be a non-empty 1-D array of integers, got {ids!r}")
        if len(set(self.ids.tolist())) != self.ids.size:
            raise TakeError(self.path, f"duplicate servo ids in {self.ids.tolist()}")
        model_ids = {int(i) for i in models}
        if model_ids != set(self.ids.tolist()):
            raise TakeError(
                self.path,
                f"models name servos {sorted(model_ids)}, ids are {sorted(self.ids.tolist())}",
            )
        self.models = {int(i): str(models[i]) for i in models}
        self.k = int(self.ids.size)
        self.count = 0
        self.fsync_interval_s = fsync_interval_s
        self._codec = fmt.ReadingCodec(self.k)
        self._ids_checked = None
        self._last_t_ns: int | None = None
        self._closed = False
        try:
            self._file = open(self.path, "wb" if overwrite else "xb")
        except FileExistsError:
            raise TakeError(self.path, "file exists; pass overwrite=True to replace it") from None
        except OSError as e:
            raise TakeError(self.path, f"cannot create take file: {e.strerror}") from e
        self._failed: str | None = None
        self._mcap = Writer(
            self._file,
            compression=CompressionType.NONE,
            use_chunking=False,
            index_types=IndexType.METADATA,
        )
        info = {
            "format_version": str(fmt.FORMAT_VERSION),
            "rig_name": str(rig_name),
            "ids": json.dumps([int(i) for i in self.ids]),
            "models": json.dumps({str(i): self.models[i] for i in sorted(self.models)}),
            "servo_count": str(self.k),
            "created_unix_ns": str(time.time_ns()),
            "rig_map_crc32": fmt.text_checksum(str(rig_map_text)),
            "calibration_crc32": fmt.text_checksum(str(calibration_text)),
        }
        info["crc32"] = fmt.info_checksum(info)
        try:
            self._mcap.start(profile="", library=f"puppet/{puppet.__version__}")
            self._mcap.add_metadata(fmt.TAKE_METADATA, info)
            self._mcap.add_metadata(fmt.RIG_MAP_METADATA, {"text": str(rig_map_text)})
            self._mcap.add_metadata(fmt.CALIBRATION_METADATA, {"text": str(calibration_text)})
            if sound is not None:
                self._mcap.add_metadata(sync.SOUND_METADATA, sound.to_metadata())
            if timecode is not None:
                self._mcap.add_metadata(sync.TIMECODE_METADATA, sync.timecode_metadata(timecode))
            if layer is not None:
                from puppet.take.layers import LAYER_METADATA

                self._mcap.add_metadata(LAYER_METADATA, layer.to_metadata())
            schema_id = self._mcap.register_schema(
                fmt.SCHEMA_NAME, fmt.SCHEMA_ENCODING, fmt.SCHEMA_TEXT.encode()
            )
            self._channel = self._mcap.register_channel(
                fmt.TOPIC,
                fmt.MESSAGE_ENCODING,
                schema_id,
                {"ids": ",".join(str(int(i)) for i in self.ids)},
            )
            self._mcap.flush()  # schema and channel records wait in mcap's builder until a flush
            os.fsync(self._file.fileno())
        except OSError as e:
            self._closed = True
            self._close_file()
            self.path.unlink(missing_ok=True)  # made here, and holds no reading
            self._fail(e, "cannot write the take's header")
        self._last_sync = time.monotonic()

    def write(self, reading: Reading) -> None:
        """Append one reading; it is in the file (OS page cache) when this returns.

        reading: Reading of this take's servos (same ids, same order); t_ns never decreasing.
        """
        if self._closed:
            raise TakeError(self.path, "write() after close()")
        if self._failed is not None:
            raise TakeError(self.path, f"write() after a failed write: {self._failed}")
        if reading.ids is not self._ids_checked:
            if not np.array_equal(reading.ids, self.ids):
                raise TakeError(
                    self.path,
                    f"reading has servo ids {np.asarray(reading.ids).tolist()}, "
                    f"take has {self.ids.tolist()}",
                )
            self._ids_checked = reading.ids
        t_ns = int(reading.t_ns)
        if self._last_t_ns is not None and t_ns < self._last_t_ns:
            raise TakeError(
                self.path, f"reading t_ns {t_ns} is earlier than the previous {self._last_t_ns}"
            )
        payload = self._codec.encode(t_ns, reading.ticks, reading.ok, reading.late)
        try:
            self._mcap.add_message(
                self._channel, log_time=t_ns, data=payload, publish_time=t_ns, sequence=self.count
            )
            self._file.flush()
        except OSError as e:
            self._fail(e, f"cannot write reading {self.count}")
        self._last_t_ns = t_ns
        self.count += 1
        if self.fsync_interval_s is not None:
            now = time.monotonic()
            if now - self._last_sync >= self.fsync_interval_s:
                try:
                    os.fsync(self._file.fileno())
                except OSError as e:
                    self._fail(e, f"cannot sync the take after reading {self.count - 1}")
                self._last_sync = now

    def _fail(self, err: OSError, doing: str) -> None:
        """A write to the take failed (full disk, I/O error): refuse further writes, and raise.

        Every reading written before stays readable (TakeReader recovers the take, which has no
        clean end); close() then only closes the file.
        """
        what = "the disk is full" if err.errno == errno.ENOSPC else (err.strerror or str(err))
        self._failed = f"{doing}: {what}; the {self.count} readings before it are kept"
        raise TakeError(self.path, self._failed) from err

    def mark(self, t_ns: int, name: str) -> None:
        """Store a named time mark (e.g. "good take") on its own channel (see puppet.take.markers);
        in the file when this returns, like a reading."""
        from puppet.take import markers

        if self._closed:
            raise TakeError(self.path, "mark() after close()")
        try:
            payload = markers.encode_marker(t_ns, name)
        except ValueError as err:
            raise TakeError(self.path, f"mark: {err}") from None
        if getattr(self, "_marker_channel", None) is None:
            schema = self._mcap.register_schema(markers.MARKER_SCHEMA_NAME, markers.MARKER_SCHEMA_ENCODING,
                                                markers.MARKER_SCHEMA.encode())
            self._marker_channel = self._mcap.register_channel(markers.MARKER_TOPIC,
                                                               markers.MARKER_MESSAGE_ENCODING, schema)
            self._marker_count = 0
        self._mcap.add_message(self._marker_channel, log_time=int(t_ns), data=payload,
                               publish_time=int(t_ns), sequence=self._marker_count)
        self._marker_count += 1
        self._mcap.flush()
        self._file.flush()

    def keys(self, keys) -> None:
        """Store a shot's keys (``puppet.take.keys.Keys``) on their own channel, each at its
        time on the shot's time line, (frame − 1) / fps (see puppet.take.keys); call it after
        writing the readings (the keys, at the same times), before close()."""
        from puppet.take import keys as key_format

        if self._closed:
            raise TakeError(self.path, "keys() after close()")
        key_format.check_frames([k.frame for k in keys.keys], self.path, keys.fps,
                                [k.id for k in keys.keys])
        schema = self._mcap.register_schema(key_format.KEY_SCHEMA_NAME,
                                            key_format.KEY_SCHEMA_ENCODING,
                                            key_format.KEY_SCHEMA.encode())
        channel = self._mcap.register_channel(key_format.KEY_TOPIC,
                                              key_format.KEY_MESSAGE_ENCODING, schema,
                                              {"fps": repr(float(keys.fps))})
        for index, (key, t_ns) in enumerate(zip(keys.keys, keys.times_ns())):
            if key.ticks.shape != (self.k,) or key.ok.shape != (self.k,):
                raise TakeError(self.path, f"key {index}: ticks {key.ticks.shape} / ok "
                                           f"{key.ok.shape}, the take has {self.k} servos")
            self._mcap.add_message(channel, log_time=int(t_ns),
                                   data=key_format.encode_key(index, key),
                                   publish_time=int(t_ns), sequence=index)
        for extra, (t_ns, data) in enumerate(keys.damaged, start=len(keys.keys)):
            # what reading skipped, kept as it was: an edit never drops what it could not read
            self._mcap.add_message(channel, log_time=int(t_ns), data=data,
                                   publish_time=int(t_ns), sequence=extra)
        self._mcap.flush()
        self._file.flush()

    def close(self) -> None:
        """Write the MCAP summary and footer, fsync and close. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._failed is not None:
            self._close_file()
            return
        try:
            self._mcap.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        except OSError as e:
            self._close_file()
            self._fail(e, "cannot finish the take")
        self._close_file()

    def _close_file(self) -> None:
        """Close the file; after a failed write its buffered bytes are dropped (they cannot
        be written, and what was written before stays readable)."""
        try:
            self._file.close()
        except OSError:
            # close() flushes again what the full disk refused; the file is closed regardless.
            return

    def __enter__(self) -> "TakeWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
