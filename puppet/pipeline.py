"""The loop that joins the parts: reading -> joint angles -> constraint values -> FAST -> image.

    source (ReaderProcess on a bus, or a take's PlaybackClock)
      -> Pipeline.solve(reading)   servo map + calibration -> Rig.fill_values -> Solver.solve
      -> Pipeline.draw()           Renderer.draw(T) -> (h, w, 3) uint8
      -> sinks                     VideoSink / PngSink / TakeWriter

The bus is read in its own process (``puppet.bus.ReaderProcess``); ``run_live`` only takes the
newest reading each frame (and every reading, for a recorder), so rendering never blocks it.
Everything the per-frame path touches is allocated once in ``Pipeline.__init__``.
"""

from __future__ import annotations

import os
import pickle
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from puppet.reading import Reading
from puppet.fast import FastModel, Pattern
from puppet.fast.errors import PatternError
from puppet.fast.live_solve import LiveSolve
from puppet.fast.factor import Factor, positional_rows
from puppet.fast.pattern import positional_entry
from puppet.rig import Rig

BONE_KIND_STATES = {"full": "sensed", "relative": "relative", "free": "free"}
ANTIALIAS = ("auto", "msaa", "fxaa", "none")
SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast", "lavapipe")
#: A live loop on a software rasterizer draws at most one triangle per this many pixels of its
#: frame (25 600 at 640x480; the critter has 49 816): see puppet.render.lod.
LIVE_PIXELS_PER_TRIANGLE = 12


def is_software_gl(gl_renderer: str) -> bool:
    """True for a CPU rasterizer (Mesa llvmpipe and its kin)."""
    return any(name in gl_renderer.lower() for name in SOFTWARE_GL)


def resolve_antialias(antialias: str, gl_renderer: str, max_samples: int) -> str:
    """The antialiasing mode to use on a GL: 'auto' becomes MSAA on a hardware GL and FXAA on a
    software rasterizer; 'msaa' on a GL without multisampling (max_samples < 2) raises
    RenderError naming the modes this GL can do."""
    from puppet.render import RenderError

    software = is_software_gl(gl_renderer)
    available = ("msaa", "fxaa", "none") if max_samples >= 2 else ("fxaa", "none")
    if antialias == "auto":
        return "fxaa" if software or "msaa" not in available else "msaa"
    if antialias not in available:
        raise RenderError(f"antialias {antialias!r}: this GL ({gl_renderer}) cannot do it "
                          f"(max samples {max_samples}); available: {', '.join(available)}")
    return antialias


@dataclass
class RigPrecompute:
    """A rig's solve precompute, made once and shared (batch workers, Ray's object store).

    model:  the FastModel (LBS matrix inputs, weights, clusters, reduced matrices Q, K).
    factor: the global step's factorization for ``rig.pattern()`` (G, P2, H).
    seconds: wall time it took to build (a cache hit in the FastModel makes it short).
    """

    model: FastModel
    factor: Factor
    seconds: float = 0.0

    @classmethod
    def for_rig(cls, rig: Rig) -> RigPrecompute:
        """Build the model and factor the rig's pattern (what every Pipeline on ``rig`` needs)."""
        start = time.perf_counter()
        options = rig.solver_options
        model = FastModel(rig.V, rig.F, rig.W, clusters=options.clusters,
                          extra_weights=options.extra_weights, energy=options.energy)
        factor = model.solver(rig.pattern()).factor
        return cls(model, factor, time.perf_counter() - start)

    def nbytes(self) -> int:
        """Size of the pickled precompute in bytes: what is sent once to each worker."""
        return len(pickle.dumps(self, protocol=pickle.HIGHEST_PROTOCOL))


class Pipeline:
    """Per-rig state that turns readings into solved transforms and rendered frames.

    rig:        the character and its servo map (calibration already applied).
    iterations: FAST local/global iterations per frame (warm-started from the last frame).
    render:     build a Renderer (False for solve-only work: exports, records).
    width, height: frame size, pixels.
    antialias:  'msaa' (4 samples), 'fxaa' (a filter over the character's rectangle on screen,
                blurring only the edge pixels), 'none', or 'auto': MSAA on a hardware GL, FXAA on
                a software rasterizer (Mesa llvmpipe), where MSAA triples the mesh pass and FXAA
                costs about 2.5 ms of CPU at 640x480, spread over the rasterizer's threads. A mode
                this GL cannot do raises RenderError naming those it can.
    overlay:    draw the skeleton with bones coloured by state.
    live:       frames for a live loop (demo, live, a view): on a software rasterizer a dense
                character is drawn simplified, one triangle per LIVE_PIXELS_PER_TRIANGLE pixels
                (Renderer's triangle_budget); False: every triangle (playback into files).
    render_options: more Renderer keywords (weight_layout, fxaa_region, ...), for benchmarks.
    precompute: a RigPrecompute of this rig made earlier (shared by many pipelines); None builds
                the model (its disk cache may make that quick) and factors the pattern here.

    Fields: model (FastModel), solver, values (the pattern's per-frame Values), T (4m, 3)
    float32 handle transforms, angles (k,) float64 radians in servo-map order, renderer.
    """

    def __init__(self, rig: Rig, *, iterations: int = 8, render: bool = True, width: int = 640,
                 height: int = 480, antialias: str = "auto", overlay: bool = False,
                 render_options: dict | None = None, precompute: RigPrecompute | None = None,
                 live: bool = False):
        if antialias not in ANTIALIAS:
            raise ValueError(f"antialias: {antialias!r} is not one of {ANTIALIAS}")
        options = rig.solver_options
        self.rig = rig
        self.iterations = int(iterations)
        self.pattern = self._rig_pattern = rig.pattern()
        if precompute is None:
            self.model = FastModel(rig.V, rig.F, rig.W, clusters=options.clusters,
                                   extra_weights=options.extra_weights, energy=options.energy)
        else:
            if precompute.model.n != len(rig.V) or precompute.model.m_bones != rig.skeleton.bone_count:
                raise ValueError(f"precompute: made for {precompute.model.n} vertices and "
                                 f"{precompute.model.m_bones} bones, the rig has {len(rig.V)} and "
                                 f"{rig.skeleton.bone_count}")
            self.model = precompute.model
        # Dropout switching and dynamics (rig options), else the plain per-frame solve.
        self.live = LiveSolve(rig, self.model) if LiveSolve.wanted(rig) else None
        if self.live is not None:
            self.solver = self.live.solver
        else:
            self.solver = self.model.solver(self.pattern,
                                            factor=precompute.factor if precompute else None)
        self.values = self.pattern.values()
        self.handle_targets = self.values.positional[len(self._rig_pattern.positional):]
        self.T = self.model.rest_T()
        self.angles = np.zeros(len(rig.servo_map), np.float64)
        self.solve_ns = 0          # time spent in Solver.solve, all frames
        self.solver_iterations = 0  # iterations run, all frames
        # Bone state per bone, and which bone each servo senses (for the "faulted" colour).
        kinds = rig.bone_kinds()
        index = {name: i for i, name in enumerate(rig.skeleton.names)}
        self._base_states = ["free"] * len(rig.skeleton.names)
        for kind, names in kinds.items():
            for name in names:
                self._base_states[index[name]] = BONE_KIND_STATES[kind]
        self._servo_bone = np.array([index[s.joint] for s in rig.servo_map.servos], np.int64)
        self.bone_states = list(self._base_states)
        sk = rig.skeleton  # rest bones for the overlay
        self.bone_segments = np.ascontiguousarray(np.stack([sk.heads, sk.tails], axis=1))  # (b, 2, 3)
        self.overlay = overlay
        self.renderer = None
        self.antialias = "none"
        if render:
            from puppet.render import RenderError, Renderer, create_context
            from puppet.render.context import gl_renderer_name

            self._context = create_context()
            try:
                antialias = resolve_antialias(antialias, gl_renderer_name(self._context),
                                              int(self._context.max_samples))
            except RenderError:
                self._context.release()
                raise
            self.antialias = antialias
            drawing = {}
            if live and is_software_gl(gl_renderer_name(self._context)):
                drawing["triangle_budget"] = width * height // LIVE_PIXELS_PER_TRIANGLE
            drawing.update(render_options or {})
            self.renderer = Renderer(rig.V, rig.F, self.model.weights, width=width, height=height,
                                     samples=4 if antialias == "msaa" else 0,
                                     fxaa=antialias == "fxaa", context=self._context, **drawing)

    def solve(self, reading: Reading) -> np.ndarray:
        """Solve this reading's pose into ``self.T`` (in place) and return it.

        A servo flagged not ok keeps the tick value the reader held for it (its last good one);
        with the rig option ``on_dropout = "free"`` its bones are solved instead once it has been
        silent long enough, and dynamics step by the readings' times (``puppet.fast.live_solve``).
        """
        rig = self.rig
        rig.servo_map.angles(reading.ticks, out=self.angles)
        start = time.perf_counter_ns()
        if self.live is not None:
            stats = self.live.solve(reading.ok, reading.t_ns, self.angles, self.T, self.iterations)
        else:
            rig.fill_values(self.angles, self.values)
            stats = self.solver.solve(self.values, self.T, iterations=self.iterations)
        self.solve_ns += time.perf_counter_ns() - start
        self.solver_iterations += int(stats.iterations)
        if not reading.ok.all():
            self._mark_faulted(reading.ok)
        elif self.bone_states != self._base_states:
            self.bone_states[:] = self._base_states
        return self.T

    def set_handles(self, points) -> float:
        """Hold these points (the live view's dragged point handles) on top of the rig's own
        constraints: a new pattern, so the solver is refactored. Returns the refactor seconds.

        points: ``Pattern.positional`` entries, each a surface point ((v0, v1, v2), (b0, b1, b2))
        (a triangle's corners and barycentric weights) or a vertex index; no repeats, none of the
        rig's pins. Their targets are the rows of ``self.handle_targets`` ((h, 3) float32, model
        units), which start where the points are in the current T (nothing jumps) and are kept
        across solves until the next call; set them before each solve. A PatternError (e.g. a
        point held only by sensed bones: redundant; a malformed point) leaves the current
        pattern in place.
        """
        if self.live is not None:  # the live solve's patterns all gain the handles
            start = time.perf_counter()
            self.live.set_handles(points, self.T)
            self.handle_targets = self.live.handle_targets
            return time.perf_counter() - start
        rig_pattern = self._rig_pattern
        handles = tuple(positional_entry(p, "handles") for p in points)
        pattern = Pattern(full=rig_pattern.full, relative=rig_pattern.relative,
                          positional=rig_pattern.positional + handles,
                          contacts=rig_pattern.contacts, limits=rig_pattern.limits)
        start = time.perf_counter()
        solver = self.model.solver(pattern)
        seconds = time.perf_counter() - start
        values = pattern.values()
        values.full[:] = self.values.full
        values.relative[:] = self.values.relative
        values.contact[:] = self.values.contact
        pins = len(rig_pattern.positional)
        values.positional[:pins] = self.values.positional[:pins]
        model = self.model
        values.positional[pins:] = positional_rows(handles, model.V, model.weights64) @ self.T.astype(np.float64)
        self.pattern, self.solver, self.values = pattern, solver, values
        self.handle_targets = values.positional[pins:]
        return seconds

    def _mark_faulted(self, ok: np.ndarray) -> None:
        self.bone_states[:] = self._base_states
        for bone in self._servo_bone[~ok]:
            self.bone_states[bone] = "faulted"

    def draw(self) -> np.ndarray:
        """Render the current T: (height, width, 3) uint8 (``render`` then ``read``)."""
        self.render()
        return self.read()

    def render(self) -> None:
        """Issue the frame of the current T (skinning and every pass; see Renderer.render)."""
        if self.renderer is None:
            raise RuntimeError("Pipeline: built with render=False")
        if self.overlay:
            self.renderer.render(self.T, bones=self.bone_segments, bone_states=self.bone_states)
        else:
            self.renderer.render(self.T)

    def read(self) -> np.ndarray:
        """Wait for the issued frame and read it back: (height, width, 3) uint8."""
        return self.renderer.read()

    def deformed(self) -> np.ndarray:
        """(n, 3) float64 deformed vertices V' = M T of the current T (CPU, for exports)."""
        return self.model.deform(self.T)

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.release()
            self._context.release()
            self.renderer = None

    def __enter__(self) -> Pipeline:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: The stages of one frame, in loop order (``Summary.stages_ms``, milliseconds per frame):
#: age: how old the reading is when the loop takes it (bus timestamp to now); solve: servo map
#: and FAST solve; draw: skinning and every render pass issued (on llvmpipe: the vertex work
#: and triangle binning, on the loop's thread); readback: waiting for the rasterizer and copying
#: the image; sinks: handing the frame to the sinks (video encoder, PNG files, live view);
#: idle: the rest of the frame: waiting for a reading, draining the reader, recording, callbacks.
#: A frame's latency is age + solve + draw + readback.
STAGES = ("age", "solve", "draw", "readback", "sinks", "idle")


class StageClock:
    """Times the loop's stages, in one place: ``lap(stage)`` charges the time since the previous
    lap to ``stage`` for the current frame; ``frame_done()`` files the frame's times into ``ms``
    ({stage: [ms per frame]}); a stage not lapped in a frame counts 0 for it."""

    def __init__(self):
        self.ms: dict[str, list[float]] = {stage: [] for stage in STAGES}
        self._frame = dict.fromkeys(STAGES, 0.0)
        self._last = time.perf_counter_ns()

    def lap(self, stage: str) -> None:
        now = time.perf_counter_ns()
        self._frame[stage] += (now - self._last) / 1e6
        self._last = now

    def set(self, stage: str, ms: float) -> None:
        """A stage measured elsewhere (the reading's age), in milliseconds."""
        self._frame[stage] = ms

    def frame_done(self) -> None:
        for stage, value in self._frame.items():
            self.ms[stage].append(value)
            self._frame[stage] = 0.0


def process_age_s() -> float | None:
    """Seconds since this process started (Linux /proc, 10 ms resolution); None elsewhere.
    A command's time to its first frame is this, taken when the first frame is done."""
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        start_ticks = int(fields[19])  # field 22 of proc(5): starttime, clock ticks after boot
        return time.clock_gettime(time.CLOCK_BOOTTIME) - start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _stat(values: list[float], q: float) -> float:
    return round(float(np.percentile(values, q)), 3) if values else float("nan")


@dataclass
class Summary:
    """What a run did. Latency runs from the servo reading's timestamp to the finished frame.

    frames: frames solved (and rendered, when rendering). seconds: wall time of the loop.
    readings: bus readings consumed. latency_ms: per frame. solver_us_per_iter: mean.
    faults: {kind: count} of bus events, plus 'servo_not_ok' readings with a flagged servo.
    stages_ms: {stage: [ms per frame]} for each of STAGES (see there).
    first_frame_s: seconds from the process's start (the command) to the first finished frame.
    """

    frames: int = 0
    seconds: float = 0.0
    readings: int = 0
    latency_ms: list[float] = field(default_factory=list)
    solver_us_per_iter: float = 0.0
    iterations_per_frame: float = 0.0
    faults: dict[str, int] = field(default_factory=dict)
    stages_ms: dict[str, list[float]] = field(default_factory=dict)
    first_frame_s: float | None = None

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def percentile_ms(self, q: float) -> float:
        return float(np.percentile(self.latency_ms, q)) if self.latency_ms else float("nan")

    def stage_stats(self) -> dict[str, dict[str, float]]:
        """{stage: {"median", "p99", "mean"}} in milliseconds per frame."""
        return {stage: {"median": _stat(ms, 50), "p99": _stat(ms, 99),
                        "mean": round(float(np.mean(ms)), 3) if ms else float("nan")}
                for stage, ms in self.stages_ms.items()}

    def as_dict(self) -> dict:
        return {
            "frames": self.frames,
            "seconds": round(self.seconds, 3),
            "readings": self.readings,
            "fps": round(self.fps, 2),
            "latency_median_ms": round(self.percentile_ms(50), 3),
            "latency_p99_ms": round(self.percentile_ms(99), 3),
            "solver_us_per_iter": round(self.solver_us_per_iter, 3),
            "iterations_per_frame": round(self.iterations_per_frame, 2),
            "faults": dict(self.faults),
            "stages_ms": self.stage_stats(),
            "first_frame_s": None if self.first_frame_s is None else round(self.first_frame_s, 3),
        }

    def text(self) -> str:
        d = self.as_dict()
        lines = [f"frames {d['frames']} in {d['seconds']} s ({d['fps']} fps), {d['readings']} readings"]
        if self.latency_ms:  # live runs only: playback has no reading-to-frame latency
            lines.append(f"latency reading->frame: median {d['latency_median_ms']} ms, "
                         f"p99 {d['latency_p99_ms']} ms")
        stages = d["stages_ms"]
        if stages:
            lines.append("stages ms median/p99: " + ", ".join(
                f"{stage} {s['median']}/{s['p99']}" for stage, s in stages.items()))
        if d["first_frame_s"] is not None:
            lines.append(f"first frame {d['first_frame_s']} s after the command started")
        lines.append(f"solver: {d['solver_us_per_iter']} us/iteration, "
                     f"{d['iterations_per_frame']} iterations/frame")
        faults = ", ".join(f"{k} {v}" for k, v in sorted(d["faults"].items())) or "none"
        lines.append(f"faults seen: {faults}")
        return "\n".join(lines)


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
    if pipeline.solver_iterations:
        summary.solver_us_per_iter = pipeline.solve_ns / 1e3 / pipeline.solver_iterations
    if summary.frames:
        summary.iterations_per_frame = pipeline.solver_iterations / summary.frames
    return summary


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


class LateLatch:
    """Late latching: each frame starts from as young a reading as the loop can get.

    With a source that reads on request (``request_reading()``: ReaderProcess), the loop asks
    for a reading just before its readback (``request``), about one bus transaction before the
    next frame starts, and that frame waits for it (at most one period, ``top_up``): the reading
    is then about one transaction old instead of up to a period older. With other sources, when
    the loop has time to spare at ``min_fps``, it waits briefly for a reading newer than the
    newest in hand (lower reading-to-frame latency, at the cost of the spare time).

    min_fps: the frame rate to keep; period_s: the source's period between readings. Without a
    request it waits only when a frame's own work (a running mean of solve..sinks) plus one
    period still fits in 1 / min_fps and the newest reading is older than half a period; it
    waits one period at most.
    """

    def __init__(self, min_fps: float, period_s: float):
        self.budget_s = 1.0 / min_fps
        self.period_s = period_s
        self.work_s = self.budget_s  # no spare time assumed until frames have been measured
        self.requested_ns = 0  # when the pending request was made (0: none)

    def note_work(self, seconds: float) -> None:
        self.work_s += 0.1 * (seconds - self.work_s)

    def request(self, source) -> None:
        """Ask ``source`` for a reading now, if it reads on request (else nothing)."""
        ask = getattr(source, "request_reading", None)
        if ask is not None:
            self.requested_ns = time.monotonic_ns()
            ask()

    def top_up(self, source, batch: list) -> list:
        """``batch`` plus any readings that came while waiting for a fresher one."""
        if self.requested_ns:
            requested_ns, self.requested_ns = self.requested_ns, 0
            return self._wait(source, batch, lambda newest: newest.t_ns >= requested_ns,
                              requested_ns / 1e9 + self.period_s)
        if self.work_s + self.period_s > self.budget_s:
            return batch
        age_s = (time.monotonic_ns() - batch[-1].t_ns) / 1e9
        if age_s < 0.5 * self.period_s:
            return batch
        held_ns = batch[-1].t_ns
        return self._wait(source, batch, lambda newest: newest.t_ns > held_ns,
                          time.monotonic_ns() / 1e9 + self.period_s)

    @staticmethod
    def _wait(source, batch: list, fresh: Callable, deadline_s: float) -> list:
        """``batch`` plus what comes until the newest reading is ``fresh`` or ``deadline_s``
        (monotonic seconds) passes."""
        while not fresh(batch[-1]) and time.monotonic_ns() / 1e9 < deadline_s:
            newer = source.drain()
            if newer:
                batch = batch + newer
            else:
                time.sleep(0.0002)
        return batch


def run_live(pipeline: Pipeline, source, *, seconds: float | None = None,
             sinks: Iterable = (), video_fps: float = 30.0, recorder=None,
             should_stop: Callable[[], bool] = lambda: False,
             on_frame: Callable[[Summary], None] | None = None,
             started_s: float | None = None, latch_fps: float | None = 60.0,
             view=None, after_solve: Callable[[Pipeline, Reading], None] | None = None) -> Summary:
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
    """
    sinks = list(sinks)
    render = bool(sinks) and pipeline.renderer is not None
    summary = Summary()
    not_ok = 0
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
        reading = batch[-1]
        stages.lap("idle")
        work_start = time.perf_counter()
        stages.set("age", (time.monotonic_ns() - reading.t_ns) / 1e6)
        if not reading.ok.all():
            not_ok += 1
        pipeline.solve(reading)
        if after_solve is not None:
            after_solve(pipeline, reading)
        stages.lap("solve")
        if render:
            image = _draw(pipeline, stages, request)
        summary.latency_ms.append((time.monotonic_ns() - reading.t_ns) / 1e6)
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
    if not_ok:
        summary.faults["servo_not_ok"] = not_ok
    return _finish(summary, pipeline)


def run_frames(pipeline: Pipeline, readings: Iterable[Reading], *, sinks: Iterable = (),
               on_frame: Callable[[Pipeline], None] | None = None,
               should_stop: Callable[[], bool] = lambda: False) -> Summary:
    """Solve (and draw into ``sinks``) one frame per reading, as fast as possible: playback.
    ``should_stop()`` (Ctrl-C, SIGTERM) ends it early, after a whole frame.

    Deterministic: the same readings give the same T on every run (fixed iterations, warm
    start from the rest pose, no wall clock in the path).
    """
    sinks = list(sinks)
    render = bool(sinks) and pipeline.renderer is not None
    summary = Summary()
    not_ok = 0
    start = time.monotonic()
    stages = StageClock()
    for reading in readings:
        if should_stop():
            break
        stages.lap("idle")  # reading the take
        not_ok += not reading.ok.all()
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
    summary.stages_ms = {stage: ms for stage, ms in stages.ms.items() if stage != "age"}
    if not_ok:
        summary.faults["servo_not_ok"] = not_ok  # flagged servos recorded in the take
    return _finish(summary, pipeline)
