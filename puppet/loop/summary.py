"""Summary: what a run did (frames, rate, latency, stages, solver, faults), in bounded memory."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

from puppet.events import describe_counts
from puppet.histogram import Histogram


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


def _stat(h: Histogram, q: float) -> float:
    return round(h.percentile(q), 3) if h.count else float("nan")


@dataclass
class Summary:
    """What a run did. Latency runs from the servo reading's timestamp to the finished frame.

    frames: frames solved (and rendered, when rendering). seconds: wall time of the loop.
    readings: bus readings consumed. latency_ms: Histogram of ms per frame (live runs).
    solver_us_per_iter: the FAST iterations' own time per iteration (native, mean).
    solve_other_us_per_frame: the rest of the solve stage per frame (angles, forward kinematics,
        constraint values, pattern switches), mean.
    faults: {kind: count} of bus events (puppet.events.EVENT_KINDS: the faults and the other events,
        'late_reply' among them), plus 'held_reading': readings with a servo's value held.
    stages_ms: {stage: Histogram of ms per frame} (see puppet.loop.stage_clock.STAGES).
    first_frame_s: seconds from the process's start (the command) to the first finished frame.
    """

    frames: int = 0
    seconds: float = 0.0
    readings: int = 0
    latency_ms: Histogram = field(default_factory=Histogram)
    solver_us_per_iter: float = 0.0
    solve_other_us_per_frame: float = 0.0
    iterations_per_frame: float = 0.0
    faults: dict[str, int] = field(default_factory=dict)
    stages_ms: dict[str, Histogram] = field(default_factory=dict)
    first_frame_s: float | None = None

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def percentile_ms(self, q: float) -> float:
        return self.latency_ms.percentile(q)

    def stage_stats(self) -> dict[str, dict[str, float]]:
        """{stage: {"median", "p99", "mean"}} in milliseconds per frame."""
        return {stage: {"median": _stat(h, 50), "p99": _stat(h, 99),
                        "mean": round(h.mean, 3) if h.count else float("nan")}
                for stage, h in self.stages_ms.items()}

    def as_dict(self) -> dict:
        return {
            "frames": self.frames,
            "seconds": round(self.seconds, 3),
            "readings": self.readings,
            "fps": round(self.fps, 2),
            "latency_median_ms": round(self.percentile_ms(50), 3),
            "latency_p99_ms": round(self.percentile_ms(99), 3),
            "solver_us_per_iter": round(self.solver_us_per_iter, 3),
            "solve_other_us_per_frame": round(self.solve_other_us_per_frame, 3),
            "iterations_per_frame": round(self.iterations_per_frame, 2),
            "faults": dict(self.faults),
            "stages_ms": self.stage_stats(),
            "first_frame_s": None if self.first_frame_s is None else round(self.first_frame_s, 3),
        }

    def text(self) -> str:
        d = self.as_dict()
        lines = [f"frames {d['frames']} in {d['seconds']} s ({d['fps']} fps), {d['readings']} readings"]
        if self.latency_ms.count:  # live runs only: playback has no reading-to-frame latency
            lines.append(f"latency reading->frame: median {d['latency_median_ms']} ms, "
                         f"p99 {d['latency_p99_ms']} ms")
        stages = d["stages_ms"]
        if stages:
            lines.append("stages ms median/p99: " + ", ".join(
                f"{stage} {s['median']}/{s['p99']}" for stage, s in stages.items()))
        if d["first_frame_s"] is not None:
            lines.append(f"first frame {d['first_frame_s']} s after the command started")
        lines.append(f"solver: {d['solver_us_per_iter']} us/iteration (the iterations alone), "
                     f"{d['iterations_per_frame']} iterations/frame; the rest of the solve stage "
                     f"(angles, kinematics, constraint values) {d['solve_other_us_per_frame']} us/frame")
        lines.append(f"faults seen: {describe_counts(d['faults'])}")  # puppet.events: faults, then the rest
        return "\n".join(lines)
