"""Recording from the page (its record button: a new take in the takes folder) and marks,
stored in that take and in the command's own ``--record`` take."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from puppet.errors import PuppetError

log = logging.getLogger("puppet.view")


class Recording:
    """take_factory: path -> an open BackgroundTakeWriter (None: the button is refused);
    takes_dir: folder of the page's takes; cli_recorder: the command's own writer or None;
    server: the ViewServer told of every change; lock: guards ``markers`` (read by snapshots);
    t0: monotonic time [s] the marks' times count from; slate: the studio
    (``puppet.view.studio_desk.StudioDesk``: ``new_take(count_in_s)`` -> (path, recorder),
    ``recorded(path)``, ``failed(path, err)``) or None: takes go to ``takes_dir``."""

    def __init__(self, take_factory, takes_dir: Path, cli_recorder, server, lock, t0: float,
                 slate=None):
        self.take_factory = take_factory
        self._slate = slate
        self.takes_dir = Path(takes_dir)
        self._cli_recorder = cli_recorder
        self._server = server
        self._lock = lock
        self._t0 = t0
        self._recorder = None
        self._path: Path | None = None
        self._last_reading = None  # the loop's newest: the time of a mark
        self.changes = 0  # starts and stops so far: a page shows no state older than its own
        self.markers: list[dict] = []

    def state(self) -> dict:
        """on, path, readings, starts_in_s (the count-in left, s) and ``changes`` (the starts
        and stops so far: the panel, sent after the messages, may carry a state the page has
        seen replaced; the page keeps the newer)."""
        changes = self.changes
        rec = self._recorder
        zero_ns = getattr(rec, "zero_ns", None)  # a count-in's end (the studio's takes)
        starts_in = None if zero_ns is None else max(0.0, (zero_ns - time.monotonic_ns()) / 1e9)
        return {"on": rec is not None, "path": str(self._path) if self._path else None,
                "readings": rec.writer.count if rec is not None else None,
                "starts_in_s": None if starts_in is None else round(starts_in, 3),
                "changes": changes}

    def set(self, on: bool, count_in_s: float = 0.0) -> None:
        """Start (a new take-STAMP.mcap, never over an existing file; the studio's: its shot's
        next take, after ``count_in_s``) or stop recording."""
        if on and self._recorder is None and self._slate is not None:
            self._path, self._recorder = self._slate.new_take(count_in_s)
            self.changes += 1
            log.warning("view: recording %s", self._path)
        elif on and self._recorder is None:
            if self.take_factory is None:
                raise PuppetError("recording is not available in this mode")
            self.takes_dir.mkdir(parents=True, exist_ok=True)
            stamp = time.strftime("%Y%m%d-%H%M%S")
            path = self.takes_dir / f"take-{stamp}.mcap"
            n = 1
            while path.exists():
                n += 1
                path = self.takes_dir / f"take-{stamp}-{n}.mcap"
            self._recorder = self.take_factory(path)
            self._path = path
            self.changes += 1
            log.warning("view: recording %s", path)
        elif not on and self._recorder is not None:
            self.close()
        self._server.send_to(None, {"type": "recording", **self.state()})

    def write(self, batch) -> None:
        """The loop's readings (the newest gives a mark its time) into the page's take while
        recording; a failing take stops, told to the pages."""
        self._last_reading = batch[-1]
        if self._recorder is None:
            return
        try:
            for item in batch:
                self._recorder.write(item)
        except PuppetError as err:
            self._server.warn(f"recording stopped: {err}", None, None)
            self._recorder = None
            self.changes += 1
            if self._slate is not None:  # the studio: a layer's base stops driving
                self._slate.failed(self._path, err)

    def mark(self, name: str) -> None:
        """A named mark at the newest reading's time (now before any) in every take being recorded."""
        reading = self._last_reading
        t_ns = reading.t_ns if reading is not None else time.monotonic_ns()
        stored = []
        for recorder in (self._recorder, self._cli_recorder):
            if recorder is not None:
                recorder.mark(t_ns, name)
                stored.append(str(recorder.path))
        if not stored:
            raise PuppetError(f"marker {name!r} not stored: nothing is recording")
        mark = {"t_s": round((t_ns / 1e9) - self._t0, 3), "name": name, "takes": stored}
        with self._lock:
            self.markers.append(mark)
        self._server.send_to(None, {"type": "marker", **mark})

    def close(self) -> None:
        """Close the page's take (complete), if one is open."""
        if self._recorder is not None:
            recorder, self._recorder = self._recorder, None
            self.changes += 1
            count = recorder.writer.count
            recorder.close()
            log.warning("view: recorded %s (%d readings)", self._path, count)
            if self._slate is not None:
                self._slate.recorded(self._path)
