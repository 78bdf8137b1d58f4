"""Recording a layer live (``puppet live --over BASE --joints head,neck --record layer.mcap``;
the studio page calls the same): the base plays from the same start as the puppeteer performs
the layer's joints.

``LayerPlan.make(rig, base, joints=..., servos=...)`` checks the request (the base's rig is the
live rig, named both otherwise; the layer holds at least one joint the puppeteer can move) and
holds the base as goal ticks of the live rig (``puppet.drive.goals.TakeGoals``: the base
composed by the one take-to-frames rule, converted through both calibrations). Then three parts
of one session, each the session's own kind of part (``layer_parts`` makes all three):

  ``BaseOverLive``  the source: the bus read live; each reading's base servos show the base at
                    that reading's play time (time 0: the first reading from the count-in's end on;
                    the base's first frame before), its layer servos what
                    the puppeteer does; the raw reading rides along (``raw_ticks``). With a
                    cycle hook it feeds the base's goals on the base's clock from a thread of its
                    own, stopped before the reader stops.
  ``BaseDrive``     an output (``Actuators``' hook and torque report): on a rig that can drive
                    (every base servo's model has a Bus Watchdog, what perform needs) the base's
                    servos are driven, torque on, through ``ActuatorHook`` in the reader process
                    (gentle start: they ease to the base; clamps, current and temperature stops,
                    Bus Watchdog, torque off on every way out). The layer's servos stay
                    sensors. A rig that cannot drive plays the base on screen only, said once.
  ``LayerTake``     the ``--record`` output: the raw readings (every servo as read), with the
                    layer record (``puppet.take.layers.LayerRef``) and the base's sound and
                    timecode.
"""

from __future__ import annotations

import copy
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from puppet.drive.actuators import ActuatorHook
from puppet.errors import PuppetError
from puppet.reading import Reading
from puppet.session.outputs import Actuators, Take, _TakeFromZero
from puppet.session.sources import BusSource

FEED_PERIOD_S = 0.002
"""How often the base's goals are handed to the reader process (its bus cycle is 2 ms at 500 Hz)."""


class LayerError(PuppetError):
    """A layer that cannot be recorded as asked (naming the option, joint, servo or rig)."""


@dataclass
class OverReading(Reading):
    """A reading shown over the base: ``ticks`` / ``ok`` composed (base servos from the base),
    ``raw_ticks`` / ``raw_ok`` as the bus read them (what the layer's take keeps)."""

    raw_ticks: np.ndarray | None = None
    raw_ok: np.ndarray | None = None


class LayerPlan:
    """What a layer recorded live plays over and holds.

    base: the base take's path; servos (l,) the layer's servo ids (rig order); goals: the base as
    goal ticks of the live rig (TakeGoals, every rig servo; the loop's), drive_goals the same for
    the goal feeder's thread; layer_cols / base_cols: column
    indexes of the rig's servos; drive: the base's servos can be driven; notes: said once.
    """

    def __init__(self, rig, base, servos, goals, sound, timecode, drive: bool, notes) -> None:
        self.rig = rig
        self.base = Path(base)
        self.servos = tuple(int(i) for i in servos)
        self.goals = goals
        self.drive_goals = copy.deepcopy(goals)  # the feeder thread's own (``at`` reuses arrays)
        self.sound = sound
        self.timecode = timecode
        self.drive = drive
        self.notes = list(notes)
        ids = [int(i) for i in rig.servo_map.ids]
        self.layer_cols = np.array([n for n, i in enumerate(ids) if i in self.servos], np.int64)
        self.base_cols = np.array([n for n, i in enumerate(ids) if i not in self.servos], np.int64)
        self.base_servos = [rig.servo_map.servos[n] for n in self.base_cols]
        self.ended = False  # the base's end was said
        self.tell = print
        self.from_ns = 0  # readings before this are a count-in's: the base holds its first frame
        self.goal_delays_ms = np.zeros(0)  # base frame -> its goal on the bus, ms (after a drive)
        self._t0_ns: int | None = None
        self._lock = threading.Lock()

    @classmethod
    def make(cls, rig, base, *, joints=(), servos=(), drive: bool = True,
             watchdog: bool = True) -> "LayerPlan":
        """Check and load: the layer's servos from ``joints`` (names) and ``servos`` (ids);
        ``drive``: drive the base where the rig can; ``watchdog``: driving needs a Bus Watchdog
        (live's --no-watchdog: not). LayerError / TakeError naming what is wrong."""
        from puppet.drive.goals import TakeGoals
        from puppet.rig.calibration import Calibration
        from puppet.servo_models import MODELS
        from puppet.take import TakeReader
        from puppet.take.layers import check_same_rig, compose

        sm = rig.servo_map
        ids = [int(i) for i in sm.ids]
        chosen: list[int] = []
        names = {s.joint for s in sm.servos}
        for joint in joints:
            if joint not in names:
                raise LayerError(f"--joints: {joint!r} is no joint with a servo in "
                                 f"{rig.path or rig.name}; joints: {sorted(names)}")
            chosen += [int(s.id) for s in sm.servos if s.joint == joint]
        for i in servos:
            if int(i) not in ids:
                raise LayerError(f"--servos: servo {i} is not in {rig.path or rig.name}; "
                                 f"servos: {ids}")
            chosen.append(int(i))
        if not chosen:
            raise LayerError("--over: name the layer's joints (--joints) or servos (--servos)")
        chosen = [i for i in ids if i in set(chosen)]
        performed = [i for i in chosen if sm.servos[ids.index(i)].role == "sensor"]
        if not performed:
            raise LayerError(f"--over: the layer's servos {chosen} are all driven (role = "
                             "\"actuator\"): nothing left to perform")
        if len(chosen) == len(ids):
            raise LayerError(f"--over: the layer holds every servo of the rig {chosen}: nothing "
                             f"of the base {base} would play (record a take instead)")
        if not Path(base).is_file():
            raise LayerError(f"--over: {base} does not exist")
        reader = TakeReader(base)
        check_same_rig(reader.metadata, rig.name, ids, layer=f"--over {base}", base=base,
                       models=dict(sm.models))
        stack = compose(reader, ids)
        zero = Calibration.from_record(reader.metadata.calibration_text, reader.path).zero_ticks
        goals = TakeGoals(sm.servos, stack.t_ns, stack.ticks, stack.ok, zero, sm.zero)
        notes = list(stack.notes)
        base_servos = [s for s in sm.servos if int(s.id) not in set(chosen)]
        can = drive and all(s.role == "sensor" for s in base_servos) and (
            not watchdog or all(MODELS[s.model].bus_watchdog_firmware is not None
                                for s in base_servos))
        if drive and not can:
            why = ("its models have no Bus Watchdog" if watchdog else "it has actuator servos")
            notes.append(f"the rig cannot drive the base ({why}): the base plays on screen only")
        return cls(rig, base, chosen, goals, reader.metadata.sound, reader.metadata.timecode,
                   can, notes)

    # ---- the base's clock ----------------------------------------------------------------------
    def start_at(self, t_ns: int) -> None:
        """Play time 0 of the base: the first reading's time at or after ``from_ns`` (the
        session's take time 0, the count-in's end; monotonic ns), as the layer's take starts
        (``puppet.session.outputs._TakeFromZero``); once. An earlier reading starts nothing."""
        with self._lock:
            if self._t0_ns is None and t_ns >= self.from_ns:
                self._t0_ns = int(t_ns)

    def play_at(self, t_ns: int) -> float:
        """The base's play time at ``t_ns``: 0 before its start (a count-in holds its first frame)."""
        play = self.play_s(t_ns)
        return 0.0 if play is None else play

    def play_s(self, t_ns: int) -> float | None:
        """The base's play time at monotonic ``t_ns`` (None before the start)."""
        t0 = self._t0_ns
        return None if t0 is None else max(0.0, (t_ns - t0) * 1e-9)

    def layer_ref(self, path):
        from puppet.take.layers import LayerRef

        return LayerRef.over(self.base, path, self.servos, rig_name=self.rig.name)


class OverBase:
    """The loop's reading source (``ReadingSource``): the reader's readings shown over the base
    (``OverReading``); everything else is the reader's (log, rate, hook, notes, torque). Used by
    ``BaseOverLive`` and by the studio's ``Switchable`` while it records a layer."""

    def __init__(self, inner, plan: LayerPlan) -> None:
        self._inner = inner
        self._plan = plan

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def _over(self, reading: Reading) -> OverReading:
        plan = self._plan
        plan.start_at(reading.t_ns)
        play = plan.play_at(reading.t_ns)
        if play > plan.goals.duration_s and not plan.ended:
            plan.ended = True
            plan.tell(f"note: the base {plan.base} ended at {plan.goals.duration_s:.2f} s: "
                      "the base holds its last frame")
        base = plan.goals.at(play)
        ticks = reading.ticks.copy()
        ok = reading.ok.copy()
        cols = plan.base_cols
        known = ~np.isnan(base[cols])
        ticks[cols[known]] = np.rint(base[cols[known]]).astype(np.int32)
        ok[cols[known]] = True
        late = None
        if reading.late is not None:  # a base servo is the base's: never late
            late = reading.late.copy()
            late[cols[known]] = False
        return OverReading(t_ns=reading.t_ns, ids=reading.ids, ticks=ticks, ok=ok, late=late,
                           raw_ticks=reading.ticks, raw_ok=reading.ok)

    def drain(self) -> list:
        return [self._over(r) for r in self._inner.drain()]

    def latest(self, timeout: float | None = 1.0):
        reading = self._inner.latest(timeout)
        return None if reading is None else self._over(reading)


class BaseOverLive(BusSource):
    """The bus read live with the layer's base shown under it (see the module docstring); with
    a cycle hook (``BaseDrive``'s) the base's goals are fed to it on the base's clock, every
    FEED_PERIOD_S, by a thread that stops before the reader does."""

    def __init__(self, rig, port: str, plan: LayerPlan, **options) -> None:
        super().__init__(rig, port, **options)
        self.plan = plan
        self.reader = None
        self._stop_feed = threading.Event()
        self._feeder: threading.Thread | None = None

    def begin(self, hooks=()) -> None:
        super().begin(hooks)
        self.reader = self.reading_source
        self.reading_source = OverBase(self.reader, self.plan)

    def ready(self, tell=None):
        report = super().ready(tell)
        if tell is not None:
            self.plan.tell = tell
            for note in self.plan.notes:
                tell(f"note: {note}")
        if self.reader.hook is not None:
            self._feeder = threading.Thread(target=self._feed, name="puppet-base-goals",
                                            daemon=True)
            self._feeder.start()
        return report

    def _feed(self) -> None:
        """The base's goals at the base's play time, to the reader process's hook. Before its
        start: during a count-in (``from_ns`` set) its first frame, so that the driven servos
        are there at time 0; without one nothing (feeding the first frame before the first
        reading made bench/layers.py's tracking 2.5 deg RMS, not 0.3: not understood yet)."""
        plan, reader, cols = self.plan, self.reader, self.plan.base_cols
        while not self._stop_feed.wait(FEED_PERIOD_S):
            now = time.monotonic_ns()
            play = plan.play_s(now)
            if play is None and plan.from_ns:
                play = 0.0
            if play is not None:
                reader.set_goals(plan.drive_goals.at(play)[cols], now)

    def stop(self) -> None:
        self._stop_feed.set()
        if self._feeder is not None:
            self._feeder.join()
            self._feeder = None
            self.plan.goal_delays_ms = self.reader.goal_delays_ms().copy()
        if isinstance(self.reading_source, OverBase):
            self.reading_source = self.reader
        super().stop()


class BaseDrive(Actuators):
    """The base's servos driven to the base (see the module docstring); nothing when the plan
    cannot drive. ``rate_hz``: the bus cycles per second; ``watchdog_ms``: as live's."""

    def __init__(self, plan: LayerPlan, rate_hz: float, *, watchdog_ms: float, tell=print) -> None:
        from puppet.drive.actuators import ActuationPlan

        self.tell = tell
        self.layer = plan
        self.plan = None
        if plan.drive:
            self.plan = ActuationPlan.for_servos(plan.rig.servo_map, plan.base_servos, rate_hz,
                                                 watchdog_ms=watchdog_ms)
            self.hook = EasedHook(self.plan)

    def open(self, run) -> None:
        self.layer.from_ns = run.record_from_ns  # the base starts at the take's time 0
        self.drive(run.source.reader)

    def drive(self, reader) -> None:
        """``reader``: the reader process whose hook drives the base (BaseOverLive's; its goals
        are fed by that source): its torque read back is said at ``close``."""
        if self.plan is not None:
            self._source = reader

    def report(self) -> dict:
        delays = self.layer.goal_delays_ms
        if self.plan is None or not len(delays):
            return {}
        return {"base goals": f"{len(self.plan.ids)} servos driven; base frame -> goal on the "
                              f"bus {np.median(delays):.1f} ms median, "
                              f"{np.percentile(delays, 99):.1f} ms p99"}


class EasedHook(ActuatorHook):
    """``ActuatorHook`` with a gentle start: after its setup (goal := present, torque on) every
    driven servo eases to the base at ``EASE_BACK_DEG_S`` before it follows at full speed."""

    def start(self, reader, note) -> list:
        changes = super().start(reader, note)
        for n in range(len(self.ids)):
            self.shaper.ease(n, self.shaper.last[n], self._slow[n])
        return changes


class LayerTake(Take):
    """``--record`` of a layer: ``layer_recorder`` from the session's take time 0 (after its
    count-in, where the base starts)."""

    def __init__(self, path, plan: LayerPlan, *, force: bool = False) -> None:
        super().__init__(path, plan.rig, force=force)
        self.layer = plan

    def check(self, inputs) -> None:
        super().check([*inputs, self.layer.base])

    def open(self, run) -> None:
        self.recorder = layer_recorder(self.layer, self.path, zero_ns=run.take_zero_ns,
                                       from_ns=run.record_from_ns, force=self.force)


def layer_recorder(plan: LayerPlan, path, *, zero_ns: int, from_ns: int, force: bool = False):
    """The take recorder of a layer (``--record``, the studio page's "record a layer"): the
    session's take recorder (``_TakeFromZero``: the file made at the first reading at or after
    ``from_ns``, the base's time 0 too) fed the raw readings (``OverReading.raw_*``), with the
    layer record and the base's sound and timecode."""
    header = {"sound": plan.sound, "timecode": plan.timecode, "layer": plan.layer_ref(path)}
    return _RawRecorder(_TakeFromZero(path, plan.rig, force=force, zero_ns=zero_ns,
                                      from_ns=from_ns, header=header))


class _RawRecorder:
    """A take recorder fed the readings as the bus read them (``write``, ``mark``, ``close``,
    ``writer``, ``started_ns``: the recorder's)."""

    def __init__(self, recorder) -> None:
        self.recorder = recorder

    def write(self, reading) -> None:
        raw = getattr(reading, "raw_ticks", None)
        if raw is not None:
            reading = Reading(reading.t_ns, reading.ids, raw, reading.raw_ok)
        self.recorder.write(reading)

    def __getattr__(self, name):
        return getattr(self.recorder, name)


def layer_parts(rig, port: str, base, take_path=None, *, joints=(), servos=(),
                baud: int = 1_000_000, rate_hz: float = 500.0, watchdog_ms: float = 100.0,
                force: bool = False, tell=print):
    """(plan, source, outputs) of a session that records a layer of ``rig`` on ``port`` over the
    take ``base``: the layer's joints by name (``joints``) and/or servo ids (``servos``); the
    take at ``take_path`` (None: the base plays and drives, nothing recorded); watchdog_ms 0:
    drive without the Bus Watchdog (--no-watchdog). Add the command's other outputs (view,
    link, video) and run ``Session(rig, source, outputs, inputs=[..., base])``. What
    ``puppet live --over`` and the studio page's "record a layer" both call."""
    plan = LayerPlan.make(rig, base, joints=joints, servos=servos, watchdog=watchdog_ms > 0)
    outputs = [BaseDrive(plan, rate_hz, watchdog_ms=watchdog_ms, tell=tell)]
    if take_path is not None:
        outputs.append(LayerTake(take_path, plan, force=force))
    return plan, BaseOverLive(rig, port, plan, baud=baud, rate_hz=rate_hz), outputs
