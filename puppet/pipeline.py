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

import pickle
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from puppet.bus import Reading
from puppet.fast import FastModel
from puppet.fast.factor import Factor
from puppet.rig import Rig

BONE_KIND_STATES = {"full": "sensed", "relative": "relative", "free": "free"}
ANTIALIAS = ("auto", "msaa", "fxaa", "none")
SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast", "lavapipe")


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
    antialias:  'msaa' (4 samples), 'fxaa' (a cheap filter pass), 'none', or 'auto': MSAA on a
                hardware GL, none on a software rasterizer (Mesa llvmpipe), where MSAA triples
                the mesh pass and FXAA adds ~3 ms: live loops keep their frame rate and latency.
    overlay:    draw the skeleton with bones coloured by state.
    precompute: a RigPrecompute of this rig made earlier (shared by many pipelines); None builds
                the model (its disk cache may make that quick) and factors the pattern here.

    Fields: model (FastModel), solver, values (the pattern's per-frame Values), T (4m, 3)
    float32 handle transforms, angles (k,) float64 radians in servo-map order, renderer.
    """

    def __init__(self, rig: Rig, *, iterations: int = 8, render: bool = True, width: int = 640,
                 height: int = 480, antialias: str = "auto", overlay: bool = False,
                 precompute: RigPrecompute | None = None):
        if antialias not in ANTIALIAS:
            raise ValueError(f"antialias: {antialias!r} is not one of {ANTIALIAS}")
        options = rig.solver_options
        self.rig = rig
        self.iterations = int(iterations)
        self.pattern = rig.pattern()
        if precompute is None:
            self.model = FastModel(rig.V, rig.F, rig.W, clusters=options.clusters,
                                   extra_weights=options.extra_weights, energy=options.energy)
            self.solver = self.model.solver(self.pattern)
        else:
            if precompute.model.n != len(rig.V) or precompute.model.m_bones != rig.skeleton.bone_count:
                raise ValueError(f"precompute: made for {precompute.model.n} vertices and "
                                 f"{precompute.model.m_bones} bones, the rig has {len(rig.V)} and "
                                 f"{rig.skeleton.bone_count}")
            self.model = precompute.model
            self.solver = self.model.solver(self.pattern, factor=precompute.factor)
        self.values = self.pattern.values()
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
            from puppet.render import Renderer, create_context
            from puppet.render.context import gl_renderer_name

            self._context = create_context()
            if antialias == "auto":
                gl_name = gl_renderer_name(self._context).lower()
                software = any(name in gl_name for name in SOFTWARE_GL)
                antialias = "none" if software else "msaa"
            self.antialias = antialias
            self.renderer = Renderer(rig.V, rig.F, self.model.weights, width=width, height=height,
                                     samples=4 if antialias == "msaa" else 0,
                                     fxaa=antialias == "fxaa", context=self._context)

    def solve(self, reading: Reading) -> np.ndarray:
        """Solve this reading's pose into ``self.T`` (in place) and return it.

        A servo flagged not ok keeps the tick value the reader held for it (its last good one).
        """
        rig = self.rig
        rig.servo_map.angles(reading.ticks, out=self.angles)
        rig.fill_values(self.angles, self.values)
        start = time.perf_counter_ns()
        stats = self.solver.solve(self.values, self.T, iterations=self.iterations)
        self.solve_ns += time.perf_counter_ns() - start
        self.solver_iterations += int(stats.iterations)
        if not reading.ok.all():
            self._mark_faulted(reading.ok)
        elif self.bone_states != self._base_states:
            self.bone_states[:] = self._base_states
        return self.T

    def _mark_faulted(self, ok: np.ndarray) -> None:
        self.bone_states[:] = self._base_states
        for bone in self._servo_bone[~ok]:
            self.bone_states[bone] = "faulted"

    def draw(self) -> np.ndarray:
        """Render the current T: (height, width, 3) uint8."""
        if self.renderer is None:
            raise RuntimeError("Pipeline: built with render=False")
        if self.overlay:
            return self.renderer.draw(self.T, bones=self.bone_segments, bone_states=self.bone_states)
        return self.renderer.draw(self.T)

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


@dataclass
class Summary:
    """What a run did. Latency runs from the servo reading's timestamp to the finished frame.

    frames: frames solved (and rendered, when rendering). seconds: wall time of the loop.
    readings: bus readings consumed. latency_ms: per frame. solver_us_per_iter: mean.
    faults: {kind: count} of bus events, plus 'servo_not_ok' readings with a flagged servo.
    """

    frames: int = 0
    seconds: float = 0.0
    readings: int = 0
    latency_ms: list[float] = field(default_factory=list)
    solver_us_per_iter: float = 0.0
    iterations_per_frame: float = 0.0
    faults: dict[str, int] = field(default_factory=dict)

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def percentile_ms(self, q: float) -> float:
        return float(np.percentile(self.latency_ms, q)) if self.latency_ms else float("nan")

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
        }

    def text(self) -> str:
        d = self.as_dict()
        lines = [f"frames {d['frames']} in {d['seconds']} s ({d['fps']} fps), {d['readings']} readings"]
        if self.latency_ms:  # live runs only: playback has no reading-to-frame latency
            lines.append(f"latency reading->frame: median {d['latency_median_ms']} ms, "
                         f"p99 {d['latency_p99_ms']} ms")
        lines.append(f"solver: {d['solver_us_per_iter']} us/iteration, "
                     f"{d['iterations_per_frame']} iterations/frame")
        faults = ", ".join(f"{k} {v}" for k, v in sorted(d["faults"].items())) or "none"
        lines.append(f"faults seen: {faults}")
        return "\n".join(lines)


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


def run_live(pipeline: Pipeline, source, *, seconds: float | None = None,
             sinks: Iterable = (), video_fps: float = 30.0, recorder=None,
             should_stop: Callable[[], bool] = lambda: False,
             on_frame: Callable[[Summary], None] | None = None) -> Summary:
    """Run the live loop until ``seconds`` pass or ``should_stop()`` (e.g. Ctrl-C).

    source:   a started ReaderProcess or ReaderThread: ``drain()``, ``latest(timeout)`` and
              ``log`` (bus events); every reading it gives is recorded (``recorder.write``), the
              newest one is solved and drawn.
    sinks:    objects with ``write(image)`` fed at ``video_fps`` by wall clock (a frame is
              repeated when the loop runs slower than the video); empty: solve only, no render.
    """
    sinks = list(sinks)
    render = bool(sinks) and pipeline.renderer is not None
    summary = Summary()
    not_ok = 0
    start = time.monotonic()
    clock = VideoClock(video_fps, start)
    image = None
    while not should_stop():
        now = time.monotonic()
        if seconds is not None and now - start >= seconds:
            break
        batch = source.drain()
        if not batch:
            newest = source.latest(timeout=0.5)
            if newest is None:
                continue
            batch = [newest]
        summary.readings += len(batch)
        if recorder is not None:
            for reading in batch:
                recorder.write(reading)
        reading = batch[-1]
        if not reading.ok.all():
            not_ok += 1
        pipeline.solve(reading)
        if render:
            image = pipeline.draw()
        summary.latency_ms.append((time.monotonic_ns() - reading.t_ns) / 1e6)
        summary.frames += 1
        if image is not None:
            for _ in range(clock.due(time.monotonic())):
                for sink in sinks:
                    sink.write(image)
        if on_frame is not None:
            on_frame(summary)
    summary.seconds = time.monotonic() - start
    summary.faults = dict(source.log.counts)
    if not_ok:
        summary.faults["servo_not_ok"] = not_ok
    return _finish(summary, pipeline)


def run_frames(pipeline: Pipeline, readings: Iterable[Reading], *, sinks: Iterable = (),
               on_frame: Callable[[Pipeline], None] | None = None) -> Summary:
    """Solve (and draw into ``sinks``) one frame per reading, as fast as possible: playback.

    Deterministic: the same readings give the same T on every run (fixed iterations, warm
    start from the rest pose, no wall clock in the path).
    """
    sinks = list(sinks)
    render = bool(sinks) and pipeline.renderer is not None
    summary = Summary()
    not_ok = 0
    start = time.monotonic()
    for reading in readings:
        not_ok += not reading.ok.all()
        pipeline.solve(reading)
        if render:
            image = pipeline.draw()
            for sink in sinks:
                sink.write(image)
        if on_frame is not None:
            on_frame(pipeline)
        summary.frames += 1
        summary.readings += 1
    summary.seconds = time.monotonic() - start
    if not_ok:
        summary.faults["servo_not_ok"] = not_ok  # flagged servos recorded in the take
    return _finish(summary, pipeline)
