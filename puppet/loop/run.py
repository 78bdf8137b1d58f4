"""The run loops: ``run_live`` (a reading source at its own pace, frames by wall clock) and
``run_frames`` (a take's frames, one after another, as fast as possible)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from functools import partial

import numpy as np

from puppet.events import HELD_READING
from puppet.loop.late_latch import LateLatch
from puppet.loop.pipeline import Pipeline
from puppet.loop.stage_clock import STAGES, StageClock
from puppet.loop.summary import Summary, process_age_s
from puppet.reading import Reading


LIVE_FPS = 60.0
"""The frame rate the live loop keeps by default (late latching's target; the link's hello)."""


class VideoClock:
    """Feeds a fixed-rate sink from a free-running loop: ``due(now)`` says how many copies of
    the newest frame the sink needs so that its timeline keeps up with wall time."""

    def __init__(self, fps: float, start_s: float):
        self.period = 1.0 / fps
        self.next_s = start_s

    def due(self, now_s: float) -> int:
        count = 0
        while now_s >= self.next_s:
            self.next_s += self.period
            count += 1
        return count


def _draw(pipeline: Pipeline, stages: StageClock, before_readback: Callable[[], None] | None = None
          ) -> np.ndarray:
    """Render the current pose and read it back: (height, width, 3) uint8; the time goes to
    the "draw" and "readback" stages. ``before_readback()`` runs between the two."""
    pipeline.render()
    stages.lap("draw")
    if before_readback is not None:
        before_readback()
    image = pipeline.read()
    stages.lap("readback")
    return image


def _finish(summary: Summary, pipeline: Pipeline) -> Summary:
    """The solver's figures: the iterations' own time per iteration, and the rest of the solve
    stage (angles, kinematics, values) per frame, kept apart."""
    if pipeline.solver_iterations:
        summary.solver_us_per_iter = pipeline.iterate_ns / 1e3 / pipeline.solver_iterations
    if summary.frames:
        summary.iterations_per_frame = pipeline.solver_iterations / summary.frames
        summary.solve_other_us_per_frame = (pipeline.solve_ns - pipeline.iterate_ns) / 1e3 / summary.frames
    return summary


def run_live(pipeline: Pipeline, source, *, seconds: float | None = None,
             sinks: Iterable = (), video_fps: float = 30.0, recorder=None,
             should_stop: Callable[[], bool] = lambda: False,
             on_frame: Callable[[Summary], None] | None = None,
             started_s: float | None = None, latch_fps: float | None = LIVE_FPS,
             view=None, after_solve: Callable[[Pipeline, Reading], None] | None = None,
             link=None, feed: Iterable[Callable[[list], None]] = ()) -> Summary:
    """Run the live loop until ``seconds`` pass or ``should_stop()`` (e.g. Ctrl-C).

    source:   a started ReaderProcess or ReaderThread: ``drain()``, ``latest(timeout)`` and
              ``log`` (bus events); every reading it gives is recorded (``recorder.write``), the
              newest one is solved and drawn.
    sinks:    objects with ``write(image)`` fed at ``video_fps`` by wall clock (a frame is
              repeated when the loop runs slower than the video); empty: solve only, no render.
    started_s: ``time.monotonic()`` when the work began, for ``Summary.first_frame_s``
              (None: the process's start, i.e. the command's).
    latch_fps: late latching (``LateLatch``) while the loop keeps this frame rate; None: off.
    view:     a live view (puppet.view.View) or None: ``view.apply(pipeline)`` before each
              solve (page input: handles, camera), ``view.frame(pipeline, batch, image, log)``
              after it (it renders for its viewers only when they can take a frame).
    after_solve: called with (pipeline, reading) right after each solve, before drawing (the
              actuators' goals from ``pipeline.T``).
    link:     a live link (puppet.link.Link) or None: ``link.frame(pipeline, reading)`` after
              each solve (it copies T; its own thread sends); with a recorder, take time 0 is
              the first reading recorded, every frame is flagged recording and its take time
              is the recorder's ``play_s`` (long gaps cut, as the take's outputs cut them).
    feed:     callables given every batch of readings (a key desk without a view).
    pipeline None: readings only (``puppet record``): every reading recorded and fed, nothing
              solved; ``frames`` then counts batches and ``held_reading`` counts readings with a held servo.
    """
    sinks = list(sinks)
    feed = list(feed)
    keep_all = recorder is not None or bool(feed)
    render = bool(sinks) and pipeline is not None and pipeline.renderer is not None
    summary = Summary()
    held = 0
    start = time.monotonic()
    clock = VideoClock(video_fps, start)
    stages = StageClock()
    rate_hz = getattr(source, "rate_hz", None)
    latch = LateLatch(latch_fps, 1.0 / rate_hz) if latch_fps and rate_hz else None
    request = None if latch is None else partial(latch.request, source)
    image = None
    while not should_stop():
        now = time.monotonic()
        if seconds is not None and now - start >= seconds:
            break
        if view is not None:
            view.apply(pipeline)
        batch = source.drain()
        if not batch:
            if keep_all:  # latest() would keep only the newest of what came meanwhile
                time.sleep(0.0005)
                continue
            newest = source.latest(timeout=0.5)
            if newest is None:
                continue
            batch = [newest]
        if latch is not None:
            batch = latch.top_up(source, batch)
        summary.readings += len(batch)
        if recorder is not None:
            for reading in batch:
                recorder.write(reading)
            if link is not None:  # take time 0: the first reading recorded
                started = getattr(recorder, "started_ns", batch[0].t_ns)
                if started is not None:
                    link.start_take(started)
        for take in feed:
            take(batch)
        if pipeline is None:  # readings only
            held += sum(not r.ok.all() for r in batch)
            summary.frames += 1
            if on_frame is not None:
                on_frame(summary)
            continue
        reading = batch[-1]
        stages.lap("idle")
        work_start = time.perf_counter()
        stages.set("age", (time.monotonic_ns() - reading.t_ns) / 1e6)
        if not reading.ok.all():
            held += 1
        pipeline.solve(reading)
        if after_solve is not None:
            after_solve(pipeline, reading)
        if link is not None:
            recording = recorder is not None and getattr(recorder, "started_ns", 0) is not None
            link.frame(pipeline, reading, recording=recording,  # the take's outputs' time line
                       take_s=getattr(recorder, "play_s", None) if recording else None)
        stages.lap("solve")
        if render:
            image = _draw(pipeline, stages, request)
        summary.latency_ms.add((time.monotonic_ns() - reading.t_ns) / 1e6)
        if summary.frames == 0:
            summary.first_frame_s = process_age_s() if started_s is None else time.monotonic() - started_s
        summary.frames += 1
        if view is not None:
            view.frame(pipeline, batch, image if render else None, source.log)
        if image is not None:
            for _ in range(clock.due(time.monotonic())):
                for sink in sinks:
                    sink.write(image)
            stages.lap("sinks")
        if latch is not None:
            latch.note_work(time.perf_counter() - work_start)
        if on_frame is not None:
            on_frame(summary)
        stages.frame_done()
    summary.seconds = time.monotonic() - start
    summary.stages_ms = stages.ms
    summary.faults = dict(source.log.counts)
    if held:
        summary.faults[HELD_READING] = held
    return summary if pipeline is None else _finish(summary, pipeline)


def run_frames(pipeline: Pipeline, readings: Iterable[Reading], *, sinks: Iterable = (),
               on_frame: Callable[[Pipeline], None] | None = None,
               should_stop: Callable[[], bool] = lambda: False) -> Summary:
    """Solve (and draw into ``sinks``) one frame per reading, as fast as possible: playback.
    ``should_stop()`` (Ctrl-C, SIGTERM) ends it early, after a whole frame.

    Deterministic: the same readings give the same T on every run (fixed iterations, warm
    start from the rest pose, no wall clock in the path). A looping clip (a ``Playback`` with
    ``loop``) is solved through once first, unused: its first frame then follows its last, so
    the bones the solver fills (and dynamics) meet at the seam as the blended servos' do.
    """
    if getattr(readings, "loop", False):
        for reading in readings:  # the pre-roll
            pipeline.solve(reading)
    sinks = list(sinks)
    render = bool(sinks) and pipeline.renderer is not None
    summary = Summary()
    held = 0
    start = time.monotonic()
    stages = StageClock(tuple(s for s in STAGES if s != "age"))
    for reading in readings:
        if should_stop():
            break
        stages.lap("idle")  # reading the take
        held += not reading.ok.all()
        pipeline.solve(reading)
        stages.lap("solve")
        if render:
            image = _draw(pipeline, stages)
            for sink in sinks:
                sink.write(image)
            stages.lap("sinks")
        if on_frame is not None:
            on_frame(pipeline)
        if summary.frames == 0:
            summary.first_frame_s = process_age_s()
        summary.frames += 1
        summary.readings += 1
        stages.frame_done()
    summary.seconds = time.monotonic() - start
    summary.stages_ms = stages.ms
    if held:
        summary.faults[HELD_READING] = held  # held servos recorded in the take
    return _finish(summary, pipeline)
