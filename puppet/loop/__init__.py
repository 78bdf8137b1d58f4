"""The loop that joins the parts: one per-frame solve path, the run loops, the stage clock and
bounded summary, and the reading-source interface.

    source (ReaderProcess on a bus, a take's frames, the view's sources)
      -> Pipeline.solve(reading)   servo map -> forward kinematics -> LiveSolve -> T
      -> Pipeline.draw()           Renderer.draw(T) -> (h, w, 3) uint8
      -> sinks                     VideoSink / PngSink / TakeWriter / live view

Modules: pipeline (Pipeline, RigPrecompute), dropout (the servo side of the solve: silent
servos' bones, dynamics steps), run (run_live, run_frames), late_latch, stage_clock, summary,
source (the ReadingSource interface).
"""

from puppet.loop.late_latch import LateLatch
from puppet.loop.pipeline import Pipeline, RigPrecompute
from puppet.loop.run import VideoClock, run_frames, run_live
from puppet.loop.source import ReadingSource
from puppet.loop.stage_clock import STAGES, StageClock
from puppet.loop.summary import Summary, process_age_s

__all__ = ["LateLatch", "Pipeline", "RigPrecompute", "ReadingSource", "STAGES", "StageClock",
           "Summary", "VideoClock", "process_age_s", "run_frames", "run_live"]
