"""A late reply from a busy host is not painted as a fault; a real fault still is. hw_sim serves
the critter's servos with its timing model: one servo's replies come late (``late``: the whole
reply, past the SDK's deadline), another's never come (``drop``). The readings cross the reader
process's shared ring (``Reading.late``) into the pipeline, whose rendered frame is checked."""

from __future__ import annotations

import numpy as np

import hw_sim
from puppet.bus.reader_process import ReaderProcess
from puppet.loop.pipeline import Pipeline
from puppet.render.overlay import BONE_STATE_COLORS

LATE_ID, FAULT_ID = 10, 13   # thigh_L, thigh_R: the two legs of the issue
LATE_MS = 25.0               # just past the reads' deadline at a 6 ms latency assumption


def _reddish(pixels: np.ndarray) -> np.ndarray:
    """(n,) bool: the overlay's fault colour (linear (1.0, 0.15, 0.1): sRGB red, little else)."""
    r, g, b = pixels[:, 0].astype(int), pixels[:, 1].astype(int), pixels[:, 2].astype(int)
    return (r > 180) & (g < 120) & (b < 120)


def _painted(pipeline: Pipeline, states: list) -> np.ndarray:
    """The pipeline's current pose drawn with these bone states."""
    return pipeline.renderer.draw(pipeline.T, bones=pipeline.bone_segments, bone_states=states).copy()


def test_a_late_reply_keeps_its_bone_colour_and_a_fault_is_painted(critter, wait_until):
    models = critter.servo_map.models
    ids = list(models)
    late_k, fault_k = ids.index(LATE_ID), ids.index(FAULT_ID)
    late_bone = critter.skeleton.index(critter.servo_map.servos[late_k].joint)
    fault_bone = critter.skeleton.index(critter.servo_map.servos[fault_k].joint)
    assert BONE_STATE_COLORS["fault"][0] > 0.9  # what _reddish looks for
    with hw_sim.serve(models, timing=True) as bus, \
            Pipeline(critter, render=True, overlay=True, width=320, height=240) as pipeline, \
            ReaderProcess(bus.port, models, rate_hz=200.0, latency_ms=6, stall_limit_s=600.0) as source:
        base = list(pipeline.bone_states)
        bus.inject("late", ids=[LATE_ID], p=0.5, ms=LATE_MS)
        bus.inject("drop", ids=[FAULT_ID])
        late_seen = []

        def both_at_once():
            for reading in source.drain():
                pipeline.solve(reading)
                if not reading.ok[late_k]:
                    late_seen.append(bool(reading.late[late_k]))
                    # never painted as a fault, whatever else the reading holds
                    assert pipeline.bone_states[late_bone] == base[late_bone], reading
                if reading.late[late_k] and pipeline.fault[fault_k]:
                    return reading
            return None

        reading = wait_until(both_at_once, timeout=120, what=f"a reading with servo {LATE_ID} late "
                             f"and servo {FAULT_ID} at fault")
        events = dict(source.log.counts)
        image = pipeline.draw().copy()
        states = list(pipeline.bone_states)
        as_if_late_were_fault = _painted(pipeline, [("fault" if i == late_bone else s)
                                                    for i, s in enumerate(states)])
        as_if_no_fault = _painted(pipeline, [(base[i] if i == fault_bone else s)
                                             for i, s in enumerate(states)])
    assert events.get("late_reply", 0) >= 1 and events.get("servo_failed", 0) + \
        events.get("servo_missing", 0) >= 1, events
    assert not reading.ok[late_k] and not reading.ok[fault_k] and not reading.late[fault_k]
    assert pipeline.fault.tolist() == [i == fault_k for i in range(len(ids))]
    assert states[fault_bone] == "fault" and states[late_bone] == base[late_bone] != "fault"
    assert all(late_seen)  # every held value of the late servo was held as late, none as a fault
    # The late servo's bone, in the frame: where it would be red if it were a fault, it is not.
    late_px = np.abs(as_if_late_were_fault.astype(int) - image).max(axis=2) > 40
    assert late_px.sum() > 20
    assert _reddish(as_if_late_were_fault[late_px]).mean() > 0.5
    assert _reddish(image[late_px]).mean() < 0.1
    # The faulted servo's bone is painted red in the same frame.
    fault_px = np.abs(as_if_no_fault.astype(int) - image).max(axis=2) > 40
    assert fault_px.sum() > 20
    assert _reddish(image[fault_px]).mean() > 0.5
