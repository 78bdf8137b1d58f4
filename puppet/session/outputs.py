"""What a session makes: one class per output, each with the same life.

    check(inputs)  before anything starts (no servo touched, no file made): the path by the one
                   output rule (``puppet.atomic``: never one of ``inputs``), the folder writable,
                   the address bound. An error names the output's option.
    open(run)      once the pipeline is built and the source is ready (``run``: the Session).
    close()        on every way out, in reverse order of opening, by the one rule for what a stop
                   keeps: everything made so far is kept and finished (a video closed and playable,
                   the take's every reading written, nothing left under a temporary name); an
                   output that made nothing leaves no file.
    report()       {name: value} lines for the run's summary.

Roles in the loop, each None where the output plays none: ``sink`` (``write(image)`` at the
video rate), ``recorder`` (``write(reading)``: every reading), ``view``, ``link``, ``hook`` (a
cycle hook inside the bus reader process), ``after_solve(pipeline, reading)``, ``feed(batch)``
(readings without a solve) and ``finished`` (the output asks the session to end).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from puppet.errors import PuppetError


class OutputError(PuppetError):
    """An output that cannot be made, naming its option."""


def _writable_folder(path: Path, option: str) -> None:
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"{option}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{option}: folder {folder} is not writable")


def close_sink(sink) -> None:
    """A frame sink by the stop rule: one that made nothing leaves no file (``abort``, where it
    has one); otherwise it is finished and closed, whatever was made kept."""
    if getattr(sink, "count", 1) == 0 and hasattr(sink, "abort"):
        sink.abort()
    else:
        sink.close()


class Output:
    """The defaults: an output that plays no role in the loop (see the module's docstring)."""

    option = ""
    renders = False  # the pipeline needs a renderer for this output
    sink = None
    recorder = None
    view = None
    link = None
    hook = None
    after_solve = None
    feed = None
    finished = False
    path: Path | None = None

    @property
    def sinks(self) -> list:
        """The frame sinks it feeds (``write(image)``)."""
        return [] if self.sink is None else [self.sink]

    def check(self, inputs) -> None:
        pass

    def open(self, run) -> None:
        pass

    def close(self) -> None:
        pass

    def report(self) -> dict:
        return {}


class Video(Output):
    """An MP4 of the frames at ``fps`` (puppet.render.VideoSink: encoded beside the loop, renamed
    into place when finished; after a SIGKILL the encoder still finishes what it was given)."""

    renders = True

    def __init__(self, path, fps: float, *, force: bool = False, option: str = "--out",
                 sound=None, sound_offset_s: float = 0.0, sound_speed: float = 1.0, timecode=None,
                 tell=print) -> None:
        self.path = Path(path)
        self.fps = fps
        self.force = force
        self.option = f"{option} {path}"
        self.sound = sound              # a puppet.sound Sound muxed in when finished (an input)
        self.sound_offset_s = sound_offset_s
        self.sound_speed = sound_speed    # take seconds per video second (play --speed)
        self.timecode = timecode
        self.tell = tell

    def check(self, inputs) -> None:
        import imageio_ffmpeg

        from puppet.atomic import check_output
        from puppet.child_signals import children_deaf_to_ctrl_c

        if self.sound is not None:
            inputs = [*inputs, self.sound.path]
        check_output(self.path, kind="video", inputs=inputs, force=self.force, what="video")
        _writable_folder(self.path, self.option)
        # found (and cached) now: its probe (``ffmpeg -version``, a child) runs no later, deaf to
        # a Ctrl-C, which is the session's (a probe killed by it read as "no ffmpeg")
        with children_deaf_to_ctrl_c():
            try:
                imageio_ffmpeg.get_ffmpeg_exe()
            except RuntimeError as err:
                raise PuppetError(f"{self.option}: no ffmpeg to encode the video ({err})") from None

    def open(self, run) -> None:
        from puppet.render import VideoSink

        self.sink = VideoSink(self.path, self.fps, sound=self.sound,
                              sound_offset_s=self.sound_offset_s, sound_speed=self.sound_speed,
                              timecode=self.timecode)

    def close(self) -> None:
        if self.sink is None:
            return
        sink, self.sink = self.sink, None
        self.frames = sink.count
        try:
            close_sink(sink)
        finally:
            for note in sink.notes if sink.count else ():  # nothing made: no file, nothing said
                self.tell(f"warning: {note}")

    def report(self) -> dict:
        return {"video": str(self.path)}


class Frames(Output):
    """Numbered PNG frames in a folder (created if missing)."""

    renders = True

    def __init__(self, folder) -> None:
        self.path = Path(folder)
        self.option = f"--frames {folder}"

    def check(self, inputs) -> None:
        from puppet.atomic import check_folder_output

        check_folder_output(self.path)
        _writable_folder(self.path, self.option)

    def open(self, run) -> None:
        from puppet.render import PngSink

        self.path.mkdir(parents=True, exist_ok=True)
        self.sink = PngSink(self.path)

    def close(self) -> None:
        if self.sink is not None:
            sink, self.sink = self.sink, None
            sink.close()

    def report(self) -> dict:
        return {"frames": str(self.path)}


def open_take_writer(path, rig, *, force: bool = False, **more):
    """A take of ``rig`` at ``path`` written on a thread of its own (a periodic fsync never
    stalls a frame): the writer every recording uses (--record, the page's record button).
    ``more``: TakeWriter's header keywords."""
    from puppet.take import BackgroundTakeWriter
    from puppet.take.header import take_writer

    return BackgroundTakeWriter(take_writer(path, rig, force=force, **more))


class _TakeFromZero:
    """The take's recorder: readings from the session's take time 0 on (after the count-in),
    the file made at the first of them (nothing recorded: no file), with the sound's reference
    (its offset: the sound's time at that first reading, so the two stay in sync by
    construction) and the start timecode of that moment. ``started_ns``: the first reading's
    time (the take's time 0; None until then); ``play_s``: the last reading's time on the
    take's outputs' time line (``PlayClock``: long gaps cut as playback cuts them). ``header``:
    TakeWriter header keywords given instead (a layer's: its record and the base's sound and
    timecode, ``puppet.session.layers``)."""

    def __init__(self, path, rig, *, force: bool, zero_ns: int, from_ns: int, sound=None,
                 sound_offset_s: float = 0.0, timecode_fps: float = 30.0,
                 header: dict | None = None) -> None:
        self.path, self.rig, self.force = path, rig, force
        self.header = header
        self.zero_ns = zero_ns   # when the sound's offset_s plays (monotonic ns)
        self.from_ns = from_ns   # readings before this are the count-in's
        self.sound, self.sound_offset_s = sound, sound_offset_s
        self.timecode_fps = timecode_fps
        self.started_ns: int | None = None
        self._writer = None  # the BackgroundTakeWriter once the first reading came
        from puppet.take.playback import PlayClock

        self._clock = PlayClock()

    @property
    def writer(self):
        """The TakeWriter (its ``count``); a stand-in counting 0 before the first reading."""
        return self._writer.writer if self._writer is not None else _NoReadings

    def _open(self, t_ns: int) -> None:
        import time

        from puppet.take import BackgroundTakeWriter
        from puppet.take.header import take_writer
        from puppet.timecode import StartTimecode, TimecodeError

        if self.header is not None:
            self._writer = BackgroundTakeWriter(take_writer(self.path, self.rig, force=self.force,
                                                            **self.header))
            self.started_ns = t_ns
            return
        sound_ref = None
        if self.sound is not None:
            from puppet.sound import sound_ref as make_ref

            sound_ref = make_ref(self.sound, self.sound_offset_s + (t_ns - self.zero_ns) / 1e9)
        unix_ns = time.time_ns() - (time.monotonic_ns() - t_ns)
        try:
            timecode = StartTimecode.from_clock(self.timecode_fps, unix_ns)
        except TimecodeError:  # a frame rate timecode has no labels for: 30 fps time of day
            timecode = StartTimecode.from_clock(30, unix_ns)
        self._writer = BackgroundTakeWriter(take_writer(self.path, self.rig, force=self.force,
                                                        sound=sound_ref, timecode=timecode))
        self.started_ns = t_ns

    def write(self, reading) -> None:
        if self._writer is None:
            if reading.t_ns < self.from_ns:
                return  # the count-in
            self._open(reading.t_ns)
        self._writer.write(reading)
        self._clock.advance(reading.t_ns)

    @property
    def play_s(self) -> float:
        return self._clock.play_ns * 1e-9

    def mark(self, t_ns: int, name: str) -> None:
        if self._writer is not None:
            self._writer.mark(t_ns, name)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()


class _NoReadings:
    count = 0


class Take(Output):
    """The raw readings into a take (``--record``, ``puppet record``): every reading from the
    session's take time 0 (after its count-in) on, with the rig's header (``puppet.take.header``),
    the sound's reference and the start timecode. The file is made at the first reading, so a
    port where nothing answers, or a stop during the count-in, makes no file."""

    def __init__(self, path, rig, *, force: bool = False, option: str = "--record") -> None:
        self.path = Path(path)
        self.rig = rig
        self.force = force
        self.option = f"{option} {path}"
        self.readings = 0

    def check(self, inputs) -> None:
        from puppet.take.header import check_take_path

        check_take_path(self.path, self.rig, force=self.force, inputs=inputs)
        _writable_folder(self.path, self.option)

    def open(self, run) -> None:
        sound = next((o for o in run.outputs if isinstance(o, Sound)), None)
        self.recorder = _TakeFromZero(self.path, self.rig, force=self.force,
                                      zero_ns=run.take_zero_ns, from_ns=run.record_from_ns,
                                      sound=sound.sound if sound else None,
                                      sound_offset_s=sound.offset_s if sound else 0.0,
                                      timecode_fps=run.video_fps)

    def close(self) -> None:
        if self.recorder is not None:
            recorder, self.recorder = self.recorder, None
            self.readings = recorder.writer.count
            recorder.close()

    def report(self) -> dict:
        return {"take": str(self.path)} if self.readings or self.recorder else \
            {"take": f"{self.path} (nothing recorded: no file)"}


class Sound(Output):
    """The sound a take is performed to (``--sound FILE``): decoded at check (a bad file named
    before anything starts), played on the machine's sound device from the session's take
    time 0 at ``offset_s`` into the sound (pre-rolled: the stream runs before; no device: said
    once, silent), its reference stored in the take (``Take``). An input: never written over."""

    def __init__(self, path, *, offset_s: float = 0.0, tell=print, device: bool = True) -> None:
        self.path = Path(path)
        self.offset_s = float(offset_s)
        self.tell = tell
        self.device = device
        self.option = ""
        self.player = None

    def check(self, inputs) -> None:
        from puppet.sound import load_sound

        self.sound = load_sound(self.path)

    def open(self, run) -> None:
        import time

        if not self.device:
            return
        from puppet.sound.device import DevicePlayer

        self.player = DevicePlayer(self.sound, self.offset_s)
        if not self.player.prepare():
            self.tell(self.player.message)
            return
        wait_s = (run.take_zero_ns - time.monotonic_ns()) / 1e9
        self.player.start(self.player.clock() + wait_s)  # heard at take time 0

    def close(self) -> None:
        if self.player is not None:
            player, self.player = self.player, None
            player.stop()

    def report(self) -> dict:
        return {"sound": f"{self.path} (from {self.offset_s:g} s)"}


class CountIn(Output):
    """The count-in before the take's time 0, said on the terminal: 3, 2, 1, then 'recording'
    (``seconds``: its length; the session's take time 0 is its end)."""

    def __init__(self, seconds: float, *, tell=print) -> None:
        self.seconds = float(seconds)
        self.tell = tell
        self.feed = self._feed

    def open(self, run) -> None:
        self._zero_ns = run.take_zero_ns
        self._said = None

    def _feed(self, batch) -> None:
        import math
        import time

        left = (self._zero_ns - time.monotonic_ns()) / 1e9
        say = "recording" if left <= 0 else str(math.ceil(left))
        if say != self._said:
            self._said = say
            self.tell(say)
        if left <= 0:
            self.feed = None


class View(Output):
    """The live view in a browser (puppet.view.View): bound at check (a taken port fails before
    anything starts), its URL said then; served once the pipeline is up. ``mode``: 'live',
    'play' or 'rig'. ``record``: the page's record button makes takes of ``rig`` in
    ``takes_dir`` (the same writer as --record). ``keys``: a KeyDesk (key poses from the page)."""

    renders = True

    def __init__(self, address: str | None, *, mode: str, rig=None, record: bool = False,
                 takes_dir=".", keys=None, tell=print) -> None:
        self.address = address
        self.mode = mode
        self.rig = rig
        self.record = record
        self.takes_dir = takes_dir
        self.keys = keys
        self.tell = tell
        self.option = "--view" + (f" {address}" if address else "")
        self.handles = 0  # point handles on the page when it closed

    def check(self, inputs) -> None:
        from puppet.view import View as LiveView

        factory = None
        if self.record:
            rig = self.rig
            factory = lambda path: open_take_writer(path, rig)  # noqa: E731
        self.view = LiveView(self.address, mode=self.mode, take_factory=factory,
                             takes_dir=self.takes_dir, keys=self.keys)  # errors name --view
        _view_log()
        self.tell(f"view: {self.view.url}")

    def open(self, run) -> None:
        recorder = next((o.recorder for o in run.outputs if o.recorder is not None), None)
        self.view.attach(run.pipeline, source=run.source.reading_source, recorder=recorder)

    def close(self) -> None:
        view = getattr(self, "view", None)
        if view is not None:
            self.view = None
            self.handles = len(view.handles())
            view.close()


class Studio(View):
    """The studio page (``puppet studio SESSION``): the live view with the session folder's
    shots and takes (puppet.view.studio_desk). At check the session folder is opened by its
    one writer (made if new; its lock taken: a second studio is refused naming the first; a
    damaged index rebuilt, said), before any servo is touched. The page's record button makes
    take N of the current shot with the session's take recorder (``_TakeFromZero``: after the
    page's count-in, with the Sound output's reference). The session's source must be a
    ``puppet.session.sources.Switchable`` (review plays a take in its place)."""

    def __init__(self, folder, address: str | None, rig, *, tell=print) -> None:
        super().__init__(address, mode="live", rig=rig, tell=tell)
        self.folder = Path(folder)
        self.writer = None

    def check(self, inputs) -> None:
        from puppet.studio import SessionWriter
        from puppet.view import View as LiveView
        from puppet.view.studio_desk import StudioDesk

        self.writer = SessionWriter.open(self.folder)
        try:
            for note in self.writer.notes:
                self.tell(f"session: {note}")
            self.desk = StudioDesk(self.writer, self.rig, open_take=self._open_take,
                                   tell=self.tell)
            self.view = LiveView(self.address, mode=self.mode, studio=self.desk)
        except BaseException:
            self.writer.close()
            self.writer = None
            raise
        _view_log()
        self.tell(f"studio: session {self.folder}")
        self.tell(f"view: {self.view.url}")

    def open(self, run) -> None:
        sound = next((o for o in run.outputs if isinstance(o, Sound)), None)
        if sound is not None:  # the shot's sound until the page chooses another
            self.desk.use_sound(sound.sound, sound.offset_s)
        self._fps = run.video_fps
        self.desk.switch = run.source  # a layer's take hands it the base (Switchable.layer)
        self.view.attach(run.pipeline, source=run.source.reading_source)

    def _open_take(self, path, zero_ns: int) -> "_TakeFromZero":
        """The session's take recorder for a take of the page, its time 0 at ``zero_ns``, with
        the sound the page uses now (``StudioDesk.performed_to``)."""
        sound, offset_s = self.desk.performed_to
        return _TakeFromZero(path, self.rig, force=False, zero_ns=zero_ns, from_ns=zero_ns,
                             sound=sound, sound_offset_s=offset_s, timecode_fps=self._fps)

    def close(self) -> None:
        try:
            super().close()
        finally:
            if self.writer is not None:
                writer, self.writer = self.writer, None
                writer.close()

    def report(self) -> dict:
        return {"session": str(self.folder)}


def _view_log() -> None:
    """The view's log lines on stderr, once."""
    logger = logging.getLogger("puppet.view")
    if not logger.handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(_ViewLogFormat())
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False


class _ViewLogFormat(logging.Formatter):
    """The view's log lines on stderr: warnings prefixed as the command line's are."""

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        return f"warning: {text}" if record.levelno >= logging.WARNING else text


class Link(Output):
    """The Blender live link (puppet.link.Link): bound at check; every solve streamed. ``fps``:
    the take's frame rate (play), or None: the loop's (live, demo). ``take``: the take's name
    (play); None: the stem of the session's --record take, if any (the add-on names a
    recording's action after it). ``sound``: (path, offset_s) of the take's sound (play);
    None: the session's ``Sound``, if any (the add-on puts it on the scene's timeline)."""

    def __init__(self, address: str | None, rig, *, fps: float | None = None,
                 take: str | None = None, sound: tuple | None = None, tell=print) -> None:
        self.address = address
        self.rig = rig
        self.fps = fps
        self.take = take
        self.sound = sound
        self.tell = tell
        self.option = "--link" + (f" {address}" if address else "")

    def check(self, inputs) -> None:
        from puppet.link import Link as LiveLink

        self._link = LiveLink(self.address, self.rig, fps=self.fps or 0.0)  # errors name --link
        self.tell(f"link: listening on {self._link.where()}")

    def open(self, run) -> None:
        from puppet.loop.run import LIVE_FPS

        self._link.take = self.take or next(
            (o.path.stem for o in run.outputs if isinstance(o, Take)), None)
        self._link.sound = self.sound or next(
            ((o.path, o.offset_s) for o in run.outputs if isinstance(o, Sound)), None)
        self._link.attach(run.pipeline, fps=None if self.fps else LIVE_FPS)
        self.link = self._link

    def close(self) -> None:
        link = getattr(self, "_link", None)
        if link is not None:
            self._link = None
            self.text = link.text()
            link.close()

    def report(self) -> dict:
        text = getattr(self, "text", None) or (self._link.text() if getattr(self, "_link", None) else None)
        return {"link": text} if text else {}


class Actuators(Output):
    """The rig's ``role = "actuator"`` servos driven to the solved angle of their joint
    (puppet.drive.actuators): a cycle hook inside the bus reader process (torque on there, off
    on every way out, Bus Watchdog set), goals handed over after each solve. ``tell``: where
    the torque read back at the end is said. None of this when the rig has no actuators."""

    def __init__(self, rig, rate_hz: float, *, watchdog_ms: float, tell=print) -> None:
        from puppet.drive.actuators import ActuationPlan, ActuatorHook, LiveActuation

        self.plan = ActuationPlan.for_rig(rig, rate_hz, watchdog_ms=watchdog_ms)
        self.tell = tell
        if self.plan is not None:
            self.hook = ActuatorHook(self.plan)
            self._actuation = LiveActuation(rig)

    def open(self, run) -> None:
        if self.plan is not None:
            self._actuation.source = run.source.reading_source
            self.after_solve = self._actuation.after_solve
            self._source = run.source.reading_source

    def close(self) -> None:
        """Said after the source stopped (the reader's hook turned torque off and read it back)."""
        source = getattr(self, "_source", None)
        if source is None:
            return
        self._source = None
        for note in source.notes:
            self.tell(note)
        after = source.torque_after
        release = f"; `puppet release --port {source.port}` turns it off"
        if not after:
            ids = [int(i) for i in source.hook.ids]
            self.tell(f"warning: actuator servos {ids}: torque not confirmed off (no read back)"
                      + release)
            return
        on = sorted(i for i, v in after.items() if v != 0)
        if on:
            self.tell(f"warning: actuator servos {on}: torque not confirmed off (read back {after})"
                      + release)
        else:
            self.tell(f"actuators {sorted(after)}: torque off (read back)")


class KeyDesk(Output):
    """Key poses into a shot (puppet.keys.capture.KeyDesk, its shot at ``path`` for ``rig``):
    readings fed to the desk each loop step (``feed``; with a view the view feeds it), commands
    from ``lines(desk)`` (the terminal's, on a thread of its own) and the page; the session ends
    when the desk is finished (``q``)."""

    def __init__(self, desk, *, path, rig, feed: bool, force: bool = False, lines=None,
                 option: str = "--keys", ready_text: str | None = None, tell=print) -> None:
        self.desk = desk
        self.ready_text = ready_text  # said once the bus answers (the first key can be taken)
        self.tell = tell
        self.path = Path(path)
        self.rig = rig
        self.force = force
        self.lines = lines
        self.option = f"{option} {path}"
        if feed:
            self.feed = self._feed

    def check(self, inputs) -> None:
        from puppet.take.header import check_take_path

        check_take_path(self.path, self.rig, force=self.force, inputs=inputs)
        _writable_folder(self.path, self.option)

    def _feed(self, batch) -> None:
        self.desk.feed(batch)
        self.desk.step()

    def open(self, run) -> None:
        import threading

        if self.ready_text is not None:
            self.tell(self.ready_text)
        if self.lines is not None:
            threading.Thread(target=self.lines, args=(self.desk,), name="puppet-key-lines",
                             daemon=True).start()

    @property
    def finished(self) -> bool:  # noqa: D102 - see the class
        return self.desk.finished

    def report(self) -> dict:
        keys = self.desk.session.keys
        frames = keys.keys[-1].frame if keys.keys else 0
        if not self.desk.session.written:  # the shot is written at its first key: none taken
            return {"shot": f"none: no key was taken, nothing written to {self.path}"}
        if self.option.startswith("--keys"):  # one line beside the run's (live --keys)
            return {"shot": f"{self.path} ({len(keys.keys)} keys)"}
        return {"shot": str(self.path), "keys": f"{len(keys.keys)}, {frames} frames at {keys.fps:g} fps"}
