"""The reading sources a session runs on: the bus (a puppet, or the simulated one of the demo),
a take on the wall clock, a take's frames one after another, and the rest pose.

Each is ``begin(hooks)`` (start, may return before the source is ready: the pipeline is built
meanwhile), ``ready()`` (wait; returns the setup report or None; raises naming the port),
``stop()`` (idempotent: every way out calls it). A live source gives the loop a
``puppet.loop.ReadingSource`` (``reading_source``); a frames source an iterable of readings
(``frames``) with its length.
"""

from __future__ import annotations

import threading
import time

from puppet.errors import PuppetError

LIVE = "live"      # run_live: a reading source at its own pace, frames by wall clock
FRAMES = "frames"  # run_frames: a take's frames, one after another


class _Starting:
    """``start()`` of a reader on a thread of its own, so that its child process (spawned: a
    fresh interpreter that imports the bus code and opens the port) gets going while the session
    builds the pipeline. ``wait()`` returns the setup report or raises the start's error."""

    def __init__(self, start) -> None:
        self._result = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(start,), name="puppet-reader-start",
                                        daemon=True)
        self._thread.start()

    def _run(self, start) -> None:
        try:
            self._result = start()
        except BaseException as err:  # noqa: BLE001 - handed to wait(), raised there
            self._error = err

    def join(self) -> None:
        self._thread.join()

    def wait(self):
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._result


def setup_lines(report, port: str) -> list[str]:
    """What the bus setup found and changed, in words (a ``SetupReport``)."""
    lines = list(report.notes)
    if report.missing:
        lines.append(f"warning: servos {report.missing} did not answer on {port}; they are flagged "
                     "and probed until they appear")
    lines += [f"servo {c.id}: {c.item} {c.old} -> {c.new}" for c in report.changes]
    return lines


class BusSource:
    """The rig's servos on ``port`` through the bus reader process (puppet.bus.ReaderProcess).

    rate_hz: steady readings per second; latency_ms: the SDK's latency assumption (None: the
    reader's default). The outputs' cycle hooks (the actuators') run inside the reader process.
    """

    kind = LIVE

    def __init__(self, rig, port: str, *, baud: int = 1_000_000, rate_hz: float = 500.0,
                 latency_ms: int | None = None) -> None:
        if not rig.servo_map.ids.size:
            raise PuppetError(f"{rig.path or rig.name}: the rig has no servos to read")
        self.rig = rig
        self.port = port
        self.baud = baud
        self.rate_hz = rate_hz
        self.latency_ms = latency_ms
        self.reading_source = None   # the ReaderProcess once begun (kept after stop: its log)
        self.link = port             # what the reader opens (the demo's: hw_sim's pty)
        self._starting: _Starting | None = None
        self._stopped = False

    def begin(self, hooks=()) -> None:
        hooks = list(hooks)
        if len(hooks) > 1:
            raise PuppetError("the bus reader takes one cycle hook")
        self.link = self._port()
        self.reading_source = self._reader(hooks[0] if hooks else None)
        self._starting = _Starting(self.reading_source.start)

    def _reader(self, hook):
        from puppet.bus.reader_process import ReaderProcess

        extra = {} if self.latency_ms is None else {"latency_ms": self.latency_ms}
        return ReaderProcess(self.link, self.rig.servo_map.models, rate_hz=self.rate_hz,
                             baud=self.baud, hook=hook, **extra)

    def hand_over(self) -> None:
        """Stop reading (the reader process ends; hw_sim, the port's server, runs on): the port
        is another reader's (a layer's, ``Switchable.layer``) until ``take_back``."""
        self.reading_source.stop()
        if self.reading_source.died is not None:
            raise PuppetError(self.reading_source.died)

    def take_back(self, tell=None):
        """Read again after ``hand_over``: a new reader process on the same port, ready."""
        from puppet.bus.reader_process import ReaderProcessError

        self.reading_source = self._reader(None)
        try:
            report = self.reading_source.start()
        except ReaderProcessError as err:
            raise PuppetError(str(err)) from None
        if tell is not None:
            for line in setup_lines(report, self.port):
                tell(line)
        return report

    def _port(self) -> str:
        return self.port

    def ready(self, tell=None):
        """Wait for the reader; its setup said through ``tell``; returns the setup report."""
        from puppet.bus.reader_process import ReaderProcessError

        try:
            report = self._starting.wait()
        except ReaderProcessError as err:
            raise PuppetError(str(err)) from None  # it names the port
        if tell is not None:
            for line in setup_lines(report, self.port):
                tell(line)
        return report

    def stop(self) -> None:
        if self._starting is not None:
            self._starting.join()
            self._starting = None
        if self.reading_source is not None and not self._stopped:
            self._stopped = True
            self.reading_source.stop()
            if self.reading_source.died is not None:  # even when the loop ended on its own
                raise PuppetError(self.reading_source.died)


class SimulatedBus(BusSource):
    """``puppet demo``'s bus: hw_sim serving the rig's servos, which play ``motion`` (and
    ``faults``), read through the same reader as hardware.

    Order: hw_sim forks its server first, while this process has no thread and no GL context
    (forking a process that has threads can deadlock the child); the reader process is then
    spawned (fork and exec at once, safe with threads).
    """

    def __init__(self, rig, motion, *, faults=None, timing: bool = True, **options) -> None:
        super().__init__(rig, port="", **options)
        self.motion = motion
        self.faults = faults
        self.timing = timing
        self._sim = None

    def _port(self) -> str:
        import hw_sim

        self._sim = hw_sim.serve(self.rig.servo_map.models, motion=self.motion, faults=self.faults,
                                 timing=self.timing, baud=self.baud)
        bus = self._sim.__enter__()
        self.port = bus.port
        return bus.link

    def stop(self) -> None:
        try:
            super().stop()
        finally:
            if self._sim is not None:
                sim, self._sim = self._sim, None
                sim.__exit__(None, None, None)


class _Ready:
    """A source ready at once (no bus): begin, ready and stop do nothing."""

    kind = LIVE
    rate_hz = None

    def begin(self, hooks=()) -> None:
        if list(hooks):
            raise PuppetError("actuators need a bus: this source has none")

    def ready(self, tell=None):
        return None

    def stop(self) -> None:
        pass


class RestPose(_Ready):
    """The rig in its rest pose (zero ticks, every servo ok): ``puppet view``, posed by handles."""

    def __init__(self, rig) -> None:
        from puppet.view import RestSource

        self.reading_source = RestSource(rig.servo_map.ids, rig.servo_map.zero)


class TakeOnClock(_Ready):
    """A take on the wall clock (``play --view``): paused, scrubbed and sped up from the page.
    ``playback``: its puppet.take.Playback; ``markers``: (play seconds, name)."""

    def __init__(self, playback, *, speed: float = 1.0, markers=()) -> None:
        from puppet.view import TakeSource

        self.reading_source = TakeSource(playback, speed=speed, markers=markers)


class TakeFrames(_Ready):
    """A take's frames (``puppet.take.Playback``, the one take-to-frames rule), solved one after
    another as fast as possible, or on the wall clock at ``speed`` (``paced``: frame k at
    start + k / (fps × speed), never early). ``take_s``: the take time of the frame being solved."""

    kind = FRAMES

    def __init__(self, playback, *, fps: float, speed: float = 1.0, paced: bool = False) -> None:
        self.playback = playback
        self.fps = float(fps)
        self.speed = float(speed)
        self.paced = paced
        self.take_s = 0.0
        self.shown_ns = 0

    def __len__(self) -> int:
        return len(self.playback)

    def frames(self, should_stop):
        """The readings to solve, in order (paced on the wall clock when ``paced``)."""
        start = time.monotonic()
        for k, reading in enumerate(self.playback):
            if self.paced:
                due = start + k / (self.fps * self.speed)
                while (wait := due - time.monotonic()) > 0 and not should_stop():
                    time.sleep(min(wait, 0.1))
            self.take_s = k / self.fps
            self.shown_ns = time.monotonic_ns()
            yield reading


class Switchable:
    """A live source (``bus``: a BusSource or SimulatedBus) whose readings the studio can swap
    for a take's (``puppet studio``: review without leaving the page). Its ``reading_source``
    hands the loop the bus's readings, or, after ``review(playback)``, those of a TakeSource on
    the wall clock (the bus reader's ring runs on; what it read meanwhile is dropped when
    ``live()`` goes back), or, after ``over(plan)``, the bus's shown over a layer's base
    (``puppet.session.layers.OverBase``, as ``puppet live --over`` shows them).
    Playback controls (pause, play, seek, set_speed, state) are the take's, refused when live.

    ``layer(plan)`` for a layer's take (the studio's "record a layer"): the readings shown over
    the base; on a rig that can drive the base (``plan.drive``) the bus is handed to the layer's
    source for the take (``BaseOverLive`` with ``BaseDrive``'s hook: the base's servos driven,
    torque on, as ``puppet live --over`` drives them) and taken back by ``unlayer`` (torque off,
    read back, said), or by ``stop`` on every way out."""

    kind = LIVE

    def __init__(self, bus, *, watchdog_ms: float = 100.0) -> None:
        self.bus = bus
        self.watchdog_ms = watchdog_ms  # a driven base's Bus Watchdog (``puppet live``'s default)
        self.reading_source = None
        self._layered = None  # (BaseOverLive, BaseDrive) while a layer drives the base
        self._stopped = False

    @property
    def rate_hz(self):
        return self.bus.rate_hz

    def begin(self, hooks=()) -> None:
        if list(hooks):
            raise PuppetError("the studio drives no actuators (use `puppet live` for a rig "
                              "with actuator servos)")
        self.bus.begin()
        self.reading_source = SwitchedReadings(self.bus.reading_source)

    def ready(self, tell=None):
        return self.bus.ready(tell)

    def layer(self, plan, tell=print) -> None:
        """Show the readings over ``plan``'s base (a LayerPlan) from its ``from_ns`` on, its
        base driven where the plan can drive (see the class)."""
        from puppet.session.layers import BaseDrive, BaseOverLive

        if plan.drive and self._layered is None:
            bus = self.bus
            drive = BaseDrive(plan, bus.rate_hz, watchdog_ms=self.watchdog_ms, tell=tell)
            layered = BaseOverLive(bus.rig, bus.link, plan, baud=bus.baud, rate_hz=bus.rate_hz,
                                   latency_ms=bus.latency_ms)
            bus.hand_over()
            try:
                layered.begin([drive.hook])
                layered.ready(None)  # (the plan's notes: said by the caller)
            except BaseException:
                try:
                    layered.stop()
                finally:
                    bus.take_back()
                    self.reading_source.use(bus.reading_source)
                raise
            drive.drive(layered.reader)
            self._layered = (layered, drive)
            self.reading_source.use(layered.reader)
        self.reading_source.over(plan)

    def unlayer(self, tell=print) -> None:
        """Back to the bus as read: a driven base's torque off (read back, said), the bus taken
        back."""
        self.reading_source.over(None)
        layered = self._layered
        if layered is None or self._stopped:
            return
        self._layered = None
        try:
            self._stop_layer(layered)
        finally:
            self.bus.take_back(tell)
            self.reading_source.use(self.bus.reading_source)

    @staticmethod
    def _stop_layer(layered) -> None:
        source, drive = layered
        try:
            source.stop()  # the feeder, then the reader: its hook turns torque off, read back
        finally:
            drive.close()  # says the torque read back

    def stop(self) -> None:
        self._stopped = True
        layered, self._layered = self._layered, None
        try:
            if layered is not None:
                self._stop_layer(layered)
        finally:
            self.bus.stop()


class SwitchedReadings:
    """The loop's reading source of a Switchable (drain, latest, log): the bus's reader or a
    take's TakeSource; switched from any thread (``review``, ``live``)."""

    def __init__(self, reader) -> None:
        self._reader = reader
        self._live = reader  # the bus's readings, or them over a layer's base (``over``)
        self._take = None  # a puppet.view.TakeSource while reviewing

    @property
    def log(self):
        return self._reader.log

    @property
    def reviewing(self) -> bool:
        return self._take is not None

    def review(self, playback, *, markers=()) -> None:
        """Show ``playback`` (a puppet.take.Playback) on the wall clock, from its start, paused."""
        from puppet.view import TakeSource

        take = TakeSource(playback, markers=markers)
        take.pause()
        self._take = take

    def live(self) -> None:
        if self._take is not None:
            self._take = None
            self._reader.drain()  # the readings of the review: not the puppet's now

    def use(self, reader) -> None:
        """Read from ``reader`` (a layer's reader process while it drives the base, the bus's
        again after)."""
        self._reader = self._live = reader

    def over(self, plan) -> None:
        """Live readings shown over ``plan``'s base (a puppet.session.layers.LayerPlan; its
        layer's servos as read, its base's from the base on the base's clock); None: as read."""
        from puppet.session.layers import OverBase

        self._live = self._reader if plan is None else OverBase(self._reader, plan)

    def drain(self):
        readings = self._live.drain()
        return readings if self._take is None else []

    def latest(self, timeout=1.0):
        take = self._take
        if take is None:
            return self._live.latest(timeout)
        return take.latest(timeout)

    def _playing(self):
        take = self._take
        if take is None:
            raise PuppetError("playback controls need a take: choose one in the list (review)")
        return take

    def pause(self) -> None:
        self._playing().pause()

    def play(self) -> None:
        self._playing().play()

    def seek(self, seconds: float) -> None:
        self._playing().seek(seconds)

    def set_speed(self, factor: float) -> None:
        self._playing().set_speed(factor)

    def state(self):
        take = self._take
        return None if take is None else take.state()

    @property
    def position_s(self) -> float | None:
        """The take's play position (s), None when live."""
        take = self._take
        return None if take is None else take.position_s
