"""The main job on the embedded default: the built-in character on a simulated bus.

``demo_source`` is ``hw_sim`` with a performance made for the rig (every sensed joint swings
within its limits, left and right half a cycle apart), read through the same ``puppet.bus``
reader as real hardware (in its own process); ``puppet demo`` runs it as a live session.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from puppet.rig import Rig, builtin
from puppet.session.outputs import Output, close_sink
from puppet.session.sources import SimulatedBus

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


def demo_source(rig: Rig, *, faults=None, timing: bool = True, baud: int = 1_000_000,
                rate_hz: float = DEMO_READ_RATE_HZ, latency_ms: int = 3) -> SimulatedBus:
    """The demo's reading source: hw_sim serving ``rig``'s servos playing its ``Performance``
    (and ``faults``: a hw_sim fault file or schedule), read by the bus reader process.
    latency_ms: the SDK's latency assumption; 3 ms leaves the simulator (a process competing
    for the same cores as the renderer and the video encoder) room to answer late."""
    return SimulatedBus(rig, Performance(rig), faults=faults, timing=timing, baud=baud,
                        rate_hz=rate_hz, latency_ms=latency_ms)


class _Given(Output):
    """Sinks, a view or a link made by the caller (benchmarks, tests) as a session output."""

    sinks: list = []  # an attribute here (the base's is a property)

    def __init__(self, *, sinks_for=None, view=None, link=None, fps=None) -> None:
        self._sinks_for, self._view, self._link, self._fps = sinks_for, view, link, fps
        self.sinks = []

    def open(self, run) -> None:
        if self._sinks_for is not None:
            self.sinks = list(self._sinks_for(run.pipeline))
        if self._view is not None:
            self._view.attach(run.pipeline, source=run.source.reading_source)
            self.view = self._view
        if self._link is not None:
            self._link.attach(run.pipeline, fps=self._fps)
            self.link = self._link

    def close(self) -> None:
        sinks, self.sinks = self.sinks, []
        for sink in sinks:
            close_sink(sink)


def run_demo(*, seconds: float | None, sinks_for: Callable[[Pipeline], list], faults=None,
             width: int = 640, height: int = 480, iterations: int = 8, video_fps: float = 30.0,
             overlay: bool = True, antialias: str = "auto", timing: bool = True,
             baud: int = 1_000_000, rate_hz: float = DEMO_READ_RATE_HZ, latency_ms: int = 3,
             render_options: dict | None = None, on_frame: Callable[[int], None] | None = None,
             latch_fps: float | None = 60.0, view=None, rig=None, link=None
             ) -> tuple[Summary, object]:
    """The demo as one session with sinks, a view or a link made by the caller (benchmarks,
    tests); ``puppet demo`` builds its session from ``demo_source`` and the session's outputs.
    Returns (summary, setup report).

    sinks_for(pipeline): the sinks to feed (e.g. a VideoSink). seconds: the run's length (None:
    until a signal). view / link: a puppet.view.View / puppet.link.Link, bound, not attached.
    on_frame(frames done): after each frame. The rest: ``demo_source`` and Pipeline keywords.
    """
    from puppet.session import Session

    rig = builtin() if rig is None else rig
    given = _Given(sinks_for=sinks_for, view=view, link=link, fps=latch_fps or rate_hz)
    session = Session(rig, demo_source(rig, faults=faults, timing=timing, baud=baud,
                                       rate_hz=rate_hz, latency_ms=latency_ms),
                      [given], seconds=seconds, video_fps=video_fps, latch_fps=latch_fps,
                      on_frame=on_frame,
                      pipeline={"iterations": iterations, "width": width, "height": height,
                                "overlay": overlay, "antialias": antialias,
                                "render_options": render_options, "live": True, "render": True})
    summary = session.run()
    return summary, session.setup
