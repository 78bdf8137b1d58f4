"""StageClock: where a frame's time goes, stage by stage, in bounded memory."""

from __future__ import annotations

import time

from puppet.histogram import Histogram

#: The stages of one frame, in loop order (milliseconds per frame):
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
    ({stage: Histogram of ms per frame}); a stage not lapped in a frame counts 0 for it."""

    def __init__(self, stages: tuple[str, ...] = STAGES):
        self.ms: dict[str, Histogram] = {stage: Histogram() for stage in stages}
        self._frame = dict.fromkeys(stages, 0.0)
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
            self.ms[stage].add(value)
            self._frame[stage] = 0.0
