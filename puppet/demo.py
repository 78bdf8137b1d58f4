"""The main job on the embedded default: the built-in character on a simulated bus.

``run_demo`` starts ``hw_sim`` with a performance made for the rig (every sensed joint swings
within its limits, left and right half a cycle apart), reads it through the same
``puppet.bus`` reader as real hardware (in its own process), and runs the live loop.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

import hw_sim
from puppet.bus.reader_process import ReaderProcess
from puppet.rig import Rig, builtin

if TYPE_CHECKING:
    from puppet.loop import Pipeline, Summary

#: The demo's steady bus rate, readings per second: twice the loop's frames. Each frame also asks
#: for a reading of its own just before it needs one (late latching), so a faster steady rate
#: would only add readings nobody draws, and their CPU (reader and simulator) to a 2-core
#: machine the renderer needs.
DEMO_READ_RATE_HZ = 120.0


class Performance:
    """A rig-aware motion source for hw_sim: ``position(servo_id, t) -> shaft counts``.

    Servo i swings sinusoidally about its zero with an amplitude of ``reach`` times the
    smaller of its two joint limits (capped at ``max_angle`` radians); servos on the right
    side ('_R' joints) run half a cycle behind the left. period_s: seconds per cycle.
    Positions are in hw_sim's motion unit, shaft counts (4096 a turn, 2048 the middle): a
    servo's own ticks (``ServoUnits``: ticks = zero + angle / radians_per_tick) through
    ``hw_sim.control_table.to_shaft`` for its model (the same on 4096-tick models; an AX-12A's
    1024 positions over 300° rescaled).
    """

    def __init__(self, rig: Rig, period_s: float = 2.4, reach: float = 0.7, max_angle: float = 0.9):
        from hw_sim.control_table import MODELS as SIM_MODELS, to_shaft

        self.period_s = period_s
        self._params: dict[int, tuple[float, float, float, float]] = {}
        units = rig.servo_map.units
        for k, servo in enumerate(rig.servo_map.servos):
            lo, hi = servo.limits
            amplitude = min(reach * min(abs(lo), abs(hi)), max_angle)
            phase = (math.pi if servo.joint.endswith("_R") else 0.0) + 0.6 * k
            spec = SIM_MODELS[servo.model].spec
            zero = float(units.zero[k])
            per_radian = 1.0 / float(units.radians_per_tick[k])   # the servo's own ticks
            self._params[int(servo.id)] = (to_shaft(spec, zero), amplitude, phase,
                                           to_shaft(spec, zero + per_radian) - to_shaft(spec, zero))

    def position(self, servo_id: int, t: float) -> float:
        zero, amplitude, phase, scale = self._params.get(int(servo_id), (2048.0, 0.0, 0.0, 0.0))
        angle = amplitude * math.sin(2 * math.pi * t / self.period_s + phase)
        return zero + angle * scale


class _Starting:
    """``source.start()`` on a thread of its own, so that the reader's child process (spawned:
    a fresh interpreter that imports the bus code and opens the port) gets going while this
    process builds the pipeline. ``wait()`` returns the setup report or raises the start's error."""

    def __init__(self, source):
        self._source = source
        self._result = None
        self._error = None
        self._thread = threading.Thread(target=self._run, name="puppet-reader-start", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._result = self._source.start()
        except BaseException as err:  # noqa: BLE001 - handed to wait(), raised there
            self._error = err

    def join(self) -> None:
        """Wait for the start to end, whatever its outcome (before stopping the source)."""
        self._thread.join()

    def wait(self):
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._result


def run_demo(*, seconds: float | None, sinks_for: Callable[[Pipeline], list], faults=None, width: int = 640,
             height: int = 480, iterations: int = 8, video_fps: float = 30.0, overlay: bool = True,
             antialias: str = "auto",
             timing: bool = True, baud: int = 1_000_000, rate_hz: float = DEMO_READ_RATE_HZ,
             latency_ms: int = 3, render_options: dict | None = None,
             should_stop: Callable[[], bool] = lambda: False,
             on_frame: Callable[[Summary], None] | None = None,
             started_s: float | None = None, latch_fps: float | None = 60.0, view=None,
             rig=None, link=None) -> tuple[Summary, object]:
    """Run the built-in character on hw_sim for ``seconds``; returns (summary, setup report).

    rig: the built-in character as loaded (default ``builtin()``; e.g. its secondary-motion
        variant ``load_rig(BUILTIN_DYNAMICS_RIG)``): the simulated servos play its performance.

    sinks_for: called with the ready Pipeline, returns the sinks to feed (e.g. a VideoSink).
    seconds: length of the run (None: until ``should_stop()``).
    faults: a hw_sim fault file (or schedule) to play during the run.
    view: a puppet.view.View (bound, not attached) to watch the run in a browser.
    link: a puppet.link.Link (bound, not attached) streaming the solves to Blender.
    rate_hz: bus readings per second (the reader process's steady rate; each frame also asks
        for a reading of its own, see puppet.loop.LateLatch).
    latency_ms: the SDK's latency assumption; 3 ms leaves the simulator (a process competing
        for the same cores as the renderer and the video encoder) room to answer late.
    render_options: more Renderer keywords (see Pipeline), for benchmarks.
    should_stop: polled every frame (Ctrl-C, SIGTERM); started_s, latch_fps: see ``run_live``.

    Order of setup: hw_sim forks its server first, while this process has no thread and no GL
    context (forking a process that has threads can deadlock the child); the reader process is
    spawned (fork and exec at once, safe with threads) and opens the bus while the pipeline
    (precompute, GL context, shaders) is built here.
    """
    rig = builtin() if rig is None else rig
    models = rig.servo_map.models
    with hw_sim.serve(models, motion=Performance(rig), faults=faults, timing=timing, baud=baud) as bus:
        source = ReaderProcess(bus.link, models, rate_hz=rate_hz, baud=baud, latency_ms=latency_ms)
        starting = _Starting(source)
        # Imported only now: the solver and renderer imports (scipy, moderngl) then overlap with
        # the reader process's own start.
        from puppet.loop import Pipeline, run_live

        try:
            with Pipeline(rig, iterations=iterations, width=width, height=height, overlay=overlay,
                          antialias=antialias, render_options=render_options, live=True) as pipeline:
                if pipeline.renderer is not None:
                    pipeline.draw()  # compiles the shaders (llvmpipe: at first use) while the reader starts
                report = starting.wait()
                sinks = sinks_for(pipeline)
                try:
                    if view is not None:
                        view.attach(pipeline, source=source)
                    if link is not None:  # frames at the loop's target rate
                        link.attach(pipeline, fps=latch_fps or rate_hz)
                    summary = run_live(pipeline, source, seconds=seconds, sinks=sinks,
                                       video_fps=video_fps, should_stop=should_stop,
                                       on_frame=on_frame, started_s=started_s, latch_fps=latch_fps,
                                       view=view, link=link)
                except BaseException:
                    for sink in sinks:  # an error or a second Ctrl-C: keep no half file
                        getattr(sink, "abort", sink.close)()
                    raise
                for sink in sinks:
                    sink.close()
        finally:
            starting.join()
            source.stop()
    return summary, report
