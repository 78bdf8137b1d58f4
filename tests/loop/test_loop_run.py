"""The live loop against hw_sim: readings flow, faults are flagged and survived."""

import time

import numpy as np
import pytest

import hw_sim
from puppet.bus import Reading
from puppet.bus.reader_process import ReaderProcess
from puppet.demo import Performance
from puppet.loop import LateLatch, Pipeline, run_frames, run_live
from puppet.render.passes.antialias import LIVE_PIXELS_PER_TRIANGLE, is_software_gl


def test_solve_follows_the_reading_and_keeps_full_constraints(critter):
    pipeline = Pipeline(critter, render=False)
    k = len(critter.servo_map)
    ticks = (critter.servo_map.zero + 200).astype(np.int32)
    pipeline.solve(Reading(0, critter.servo_map.ids, ticks, np.ones(k, bool)))
    T = pipeline.T.reshape(-1, 4, 3)
    for i, bone in enumerate(critter.full_bones):
        np.testing.assert_allclose(T[bone], pipeline.values.full[i], atol=1e-4)
    assert not np.allclose(T[critter.full_bones[1]][:3], np.eye(3), atol=1e-3)
    assert np.isfinite(pipeline.T).all()


def test_a_servo_at_fault_marks_its_bone_a_late_one_does_not(critter):
    pipeline = Pipeline(critter, render=False)
    k = len(critter.servo_map)
    ids, zero = critter.servo_map.ids, critter.servo_map.zero.astype(np.int32)
    ok = np.ones(k, bool)
    ok[0] = ok[1] = False
    late = np.zeros(k, bool)
    late[1] = True  # servo 1's reply came late: held, not a fault
    bone = critter.skeleton.index(critter.servo_map.servos[0].joint)
    late_bone = critter.skeleton.index(critter.servo_map.servos[1].joint)
    base = list(pipeline.bone_states)
    pipeline.solve(Reading(0, ids, zero, ok, late=late))
    assert pipeline.bone_states[bone] == "fault"
    assert pipeline.bone_states[late_bone] == base[late_bone] != "fault"
    assert pipeline.fault.tolist() == [True] + [False] * (k - 1)
    pipeline.solve(Reading(1, ids, zero, np.ones(k, bool)))
    assert pipeline.bone_states == base
    pipeline.solve(Reading(2, ids, zero, ok))  # no late mask (a take): every held servo at fault
    assert pipeline.bone_states[bone] == pipeline.bone_states[late_bone] == "fault"


def test_live_loop_keeps_running_through_faults(critter):
    models = critter.servo_map.models
    ids = [int(i) for i in critter.servo_map.ids]
    pipeline = Pipeline(critter, render=False)
    with hw_sim.serve(models, motion=Performance(critter), timing=False) as bus:
        with ReaderProcess(bus.port, models, rate_hz=200.0, latency_ms=1) as source:
            recorded = []

            class Recorder:
                def write(self, reading):
                    recorded.append(reading)

            def booked(dxl_id, kinds=("servo_failed", "servo_missing")):
                return any(e.kind in kinds and dxl_id in e.ids for e in source.log.events)

            # Faults follow the states the loop reaches, not a timer: drop a servo until it is
            # booked failed, end the drop, power another off until it is booked, power it on,
            # run until both have recovered and the readings are whole again.
            steps = [
                (lambda: len(recorded) > 0, lambda: bus.inject("drop", ids=[ids[2]])),
                (lambda: booked(ids[2]), bus.clear_faults),
                (lambda: booked(ids[2], ["servo_recovered"]), lambda: bus.inject("power_off", ids=[ids[5]])),
                (lambda: booked(ids[5]), lambda: bus.inject("power_on", ids=[ids[5]])),
                (lambda: booked(ids[5], ["servo_recovered"]) and recorded[-1].ok.all(), lambda: None),
            ]

            def should_stop():
                while steps and steps[0][0]():
                    steps.pop(0)[1]()
                return not steps

            summary = run_live(pipeline, source, seconds=120, recorder=Recorder(), should_stop=should_stop)
        assert source.dropped == 0
    assert steps == []
    assert summary.frames >= 1
    assert np.isfinite(pipeline.T).all()
    flagged = {int(r.ids[j]) for r in recorded for j in np.flatnonzero(~r.ok)}
    assert {ids[2], ids[5]} <= flagged
    assert summary.faults.get("held_reading", 0) >= 1
    assert recorded[-1].ok.all()  # recovered by the end
    assert summary.readings == len(recorded)


def test_playback_is_deterministic(critter):
    rng = np.random.default_rng(5)
    k = len(critter.servo_map)
    readings = [Reading(i * 10_000_000, critter.servo_map.ids,
                        (critter.servo_map.zero + rng.integers(-300, 300, k)).astype(np.int32),
                        np.ones(k, bool)) for i in range(12)]
    runs = []
    for _ in range(2):
        pipeline = Pipeline(critter, render=False)
        frames = []
        run_frames(pipeline, readings, on_frame=lambda p: frames.append(p.deformed()))
        runs.append(np.stack(frames))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.allclose(runs[0][0], runs[0][-1])


def test_antialias_auto_picks_fxaa_on_a_software_renderer(critter):
    with Pipeline(critter, width=64, height=48) as pipeline:
        software = "llvmpipe" in pipeline.renderer.gl_renderer
        assert pipeline.antialias == ("fxaa" if software else "msaa")
        assert pipeline.renderer.fxaa == software
        image = pipeline.draw()
        assert image.shape == (48, 64, 3)


def test_antialias_a_gl_cannot_do_names_what_it_can():
    from puppet.render.passes.antialias import resolve_antialias
    from puppet.render import RenderError

    with pytest.raises(RenderError, match=r"antialias 'msaa': this GL \(some GL\) cannot do it "
                                          r"\(max samples 1\); available: fxaa, none"):
        resolve_antialias("msaa", "some GL", max_samples=1)
    assert resolve_antialias("auto", "some GL", max_samples=1) == "fxaa"
    assert resolve_antialias("auto", "NVIDIA H100", max_samples=8) == "msaa"
    assert resolve_antialias("auto", "llvmpipe (LLVM 15.0.6, 256 bits)", max_samples=4) == "fxaa"
    assert resolve_antialias("msaa", "llvmpipe (LLVM 15.0.6, 256 bits)", max_samples=4) == "msaa"


def test_antialias_must_be_known(critter):
    with pytest.raises(ValueError, match="antialias"):
        Pipeline(critter, render=False, antialias="smooth")


class _RequestedSource:
    """A source that reads on request: the reading comes a few drains after the request."""

    def __init__(self):
        self.asked = 0
        self._due = None

    def request_reading(self):
        self.asked += 1
        self._due = 3

    def drain(self):
        if self._due is None:
            return []
        self._due -= 1
        if self._due:
            return []
        self._due = None
        return [Reading(time.monotonic_ns(), np.array([1]), np.zeros(1, np.int32), np.ones(1, bool))]


def test_late_latch_waits_for_the_reading_it_asked_for():
    source = _RequestedSource()
    latch = LateLatch(min_fps=60.0, period_s=1e3)  # a period far longer than the test
    old = Reading(time.monotonic_ns(), np.array([1]), np.zeros(1, np.int32), np.ones(1, bool))
    latch.request(source)
    asked_ns = latch.requested_ns
    batch = latch.top_up(source, [old])
    assert source.asked == 1
    assert batch[0] is old and batch[-1].t_ns >= asked_ns
    assert latch.top_up(source, [old]) == [old]  # no request pending, no spare time: no wait


def test_late_latch_asks_only_sources_that_read_on_request():
    latch = LateLatch(min_fps=60.0, period_s=0.004)
    latch.request(object())
    assert latch.requested_ns == 0


def test_a_live_pipeline_draws_the_simplified_character_on_a_software_renderer(critter):
    """Live loops draw one triangle per LIVE_PIXELS_PER_TRIANGLE pixels on llvmpipe (every
    triangle on a GPU); playback into files draws every triangle."""
    with Pipeline(critter, live=True) as live, Pipeline(critter) as files:
        assert files.renderer.drawn_triangles == len(critter.F)
        software = is_software_gl(live.renderer.gl_renderer)
        budget = 640 * 480 // LIVE_PIXELS_PER_TRIANGLE
        assert budget < len(critter.F)
        assert live.renderer.drawn_triangles == (budget if software else len(critter.F))
