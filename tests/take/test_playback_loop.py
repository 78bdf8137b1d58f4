"""A looping clip's seam blended in solve space by the one take-to-frames rule
(``Playback.clip(..., loop=True)``): the jump from its last frame back to its first is no larger
than the clip's median frame-to-frame motion, where the unblended clip's jump is many times it."""

import numpy as np
import pytest

from puppet.rig import builtin
from puppet.take import Playback
from puppet.take.errors import TakeError


def _motion(a: np.ndarray, b: np.ndarray) -> float:
    """The largest joint rotation angle (rad) between two frames' (b, 3, 3) rotations."""
    rel = np.einsum("bij,bkj->bik", b, a)
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.max(np.arccos(cos)))


@pytest.fixture(scope="module")
def rig():
    return builtin()


def _take(rig, seconds=3.0, rate_hz=120.0):
    ids = rig.servo_map.ids
    k = len(ids)
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    zero = np.asarray(rig.servo_map.zero, float)
    ticks = zero + 250 * np.sin(2 * np.pi * 0.7 * t[:, None] + np.arange(k)[None, :])
    return Playback((1_000_000_000 + t * 1e9).astype(np.int64), ticks.astype(np.int32),
                    np.ones((len(t), k), bool), ids, fps=30.0, source="synthetic.mcap")


def _rotations(rig):
    def joint_rotations(ticks):
        return rig.skeleton.joint_rotations(rig.servo_map.angles(ticks.astype(np.int32))).copy()
    return joint_rotations


def test_a_looping_clip_has_no_pop_at_its_seam(rig):
    take = _take(rig)
    rotations = _rotations(rig)
    loop = take.clip(0.3, 2.1, loop=True, joint_rotations=rotations)
    frames = [loop.reading(f).rotations for f in range(len(loop))]
    steps = [_motion(a, b) for a, b in zip(frames, frames[1:])]
    seam = _motion(frames[-1], frames[0])
    assert seam <= np.median(steps) + 1e-9, (seam, np.median(steps))

    plain = take.clip(0.3, 2.1)
    raw = [rotations(plain.reading(f).ticks) for f in range(len(plain))]
    assert len(raw) == len(frames) == round(1.8 * 30) + 1
    raw_seam = _motion(raw[-1], raw[0])
    assert raw_seam > 5 * np.median(steps)  # the clip chosen does pop without the blend
    # before the blend the frames are the take's own
    assert np.allclose(frames[5], raw[5])


def test_a_clip_keeps_the_take_frames_and_refuses_a_bad_span(rig):
    take = _take(rig)
    clip = take.clip(0.5, 1.5)
    assert clip.duration_s == pytest.approx(1.0)
    assert np.array_equal(clip.at(0.25).ticks, take.at(0.75).ticks)
    with pytest.raises(TakeError, match="out point must come after"):
        take.clip(1.5, 0.5)


def test_a_clip_past_the_takes_end_says_so_and_one_starting_past_it_is_refused(rig):
    take = _take(rig)
    end = take.duration_s
    clip = take.clip(0.5, end + 100)
    assert clip.duration_s == pytest.approx(end - 0.5)
    assert clip.notes == [f"{take.source}: clip 0.5-{end + 100:g} s: the take ends at {end:.3f} s: "
                          f"the clip is 0.5-{end:.3f} s"]
    assert take.clip(0.5, end).notes == []  # to the end exactly: as asked
    with pytest.raises(TakeError, match=rf"clip 100-200 s: the in point is at or past the take's "
                                        rf"end, {end:.3f} s"):
        take.clip(100, 200)
    with pytest.raises(TakeError, match="out point must come after"):
        take.clip(200, 100)


def test_a_loop_ending_on_a_fast_move_has_no_pop_at_its_seam(rig):
    """The out point in a fast move (the last 0.2 s six times as fast as the rest): the seam is
    one step no larger than the clip's median step, not the fast last step (it was: a pop of
    several frames' motion)."""
    ids = rig.servo_map.ids
    k = len(ids)
    rate_hz = 120.0
    t = np.arange(int(3.0 * rate_hz)) / rate_hz
    phase = 2 * np.pi * (0.3 * t + 1.5 * np.clip(t - 1.9, 0.0, None))
    zero = np.asarray(rig.servo_map.zero, float)
    ticks = zero + 250 * np.sin(phase[:, None] + np.arange(k)[None, :])
    take = Playback((1_000_000_000 + t * 1e9).astype(np.int64), ticks.astype(np.int32),
                    np.ones((len(t), k), bool), ids, fps=30.0, source="synthetic.mcap")
    rotations = _rotations(rig)
    plain = take.clip(0.3, 2.1)
    raw = [rotations(plain.reading(f).ticks) for f in range(len(plain))]
    raw_steps = [_motion(a, b) for a, b in zip(raw, raw[1:])]
    assert raw_steps[-1] > 3 * np.median(raw_steps)  # the clip does end on a fast move
    loop = take.clip(0.3, 2.1, loop=True, joint_rotations=rotations)
    frames = [loop.reading(f).rotations for f in range(len(loop))]
    steps = [_motion(a, b) for a, b in zip(frames, frames[1:])]
    seam = _motion(frames[-1], frames[0])
    assert 0 < seam <= np.median(steps), (seam, np.median(steps))
    assert np.allclose(frames[5], raw[5])  # before the blend the frames are the take's own


def test_the_solved_bones_meet_at_a_loops_seam(rig):
    """Solved (``run_frames``), a looping clip is pre-rolled: every handle's jump from the last
    frame to the first, the solver-filled bones' (spine, ears, tail) too, is within the clip's
    largest frame-to-frame step (without the pre-roll the tail's was 1.3-1.7 times it: the first
    frame solved from the rest pose, the last from the clip's history)."""
    from puppet.loop import Pipeline, run_frames

    loop = _take(rig).clip(0.3, 2.1, loop=True, joint_rotations=_rotations(rig))
    solved = []
    with Pipeline(rig, render=False) as pipeline:
        summary = run_frames(pipeline, loop, on_frame=lambda p: solved.append(p.T.copy()))
    assert summary.frames == len(loop) == len(solved)  # the pre-roll is not a frame
    blocks = np.array(solved).reshape(len(solved), -1, 4, 3)  # (frames, handles, 4, 3)
    steps = np.abs(np.diff(blocks, axis=0)).max(axis=(2, 3))  # (frames - 1, handles)
    seam = np.abs(blocks[-1] - blocks[0]).max(axis=(1, 2))
    moving = steps.max(axis=0) > 0
    assert np.all(seam[moving] <= steps.max(axis=0)[moving]), seam / steps.max(axis=0)
