"""A layer composed over its base by the one take-to-frames rule (puppet.take.layers through
Playback.of_take): the base's servos as the base plays them, the layer's as performed; punch
seams blended without a pop; mute, solo; the top layer wins; the refusals."""

from __future__ import annotations

import numpy as np
import pytest

from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_RIG
from puppet.take import Playback, TakeError, TakeReader, TakeWriter
from puppet.take.header import take_header
from puppet.take.layers import LayerOptions, LayerRef, compose

RATE_HZ = 100
FPS = 30.0


@pytest.fixture(scope="module")
def rig():
    return load_rig(BUILTIN_RIG)


def _motion(ids, t, phase):
    """(len(t), k) ticks: a slow sine per servo, ``phase`` apart between passes."""
    ids = np.asarray(ids, float)
    return (2048 + 300 * np.sin(2 * np.pi * (0.3 + 0.05 * ids)[None, :] * t[:, None]
                                + phase + ids[None, :])).astype(np.int32)


def _write(path, rig, seconds, phase, *, start_ns, layer=None, rig_name=None, raw_other=None):
    header = take_header(rig)
    if rig_name is not None:
        header["rig_name"] = rig_name
    ids = header["ids"]
    t = np.arange(int(seconds * RATE_HZ) + 1) / RATE_HZ
    ticks = _motion(ids, t, phase)
    if raw_other is not None:  # the servos the layer does not hold: what the bus read (unused)
        held = set(layer.servos)
        for n, i in enumerate(ids):
            if i not in held:
                ticks[:, n] = raw_other
    with TakeWriter(path, **header, layer=layer) as w:
        from puppet.reading import Reading

        for r in range(len(t)):
            w.write(Reading(start_ns + int(t[r] * 1e9), np.asarray(ids), ticks[r],
                            np.ones(len(ids), bool)))
    return path


def _layer(tmp_path, rig, base, servos, name="layer.mcap", seconds=3.0, phase=1.0, **punch):
    path = tmp_path / name
    ref = LayerRef.over(base, path, servos, rig_name=rig.name, **punch)
    return _write(path, rig, seconds, phase, start_ns=7_000_000_000, layer=ref, raw_other=100)


def _frames(path, rig, **options):
    with TakeReader(path) as reader:
        return Playback.of_take(reader, rig.servo_map.ids, fps=FPS, **options)


def _ticks(playback):
    return np.stack([r.ticks for r in playback]).astype(np.int64)


def test_a_layer_plays_its_servos_over_the_base_s_others(tmp_path, rig):
    base = _write(tmp_path / "base.mcap", rig, 3.0, 0.0, start_ns=1_000_000_000)
    layer = _layer(tmp_path, rig, base, [1, 2, 3])
    composed = _ticks(_frames(layer, rig))
    alone = _ticks(_frames(base, rig))
    raw = _ticks(_frames(layer, rig, layers=LayerOptions(mute=frozenset({layer}))))
    assert composed.shape == alone.shape
    np.testing.assert_array_equal(composed[:, 3:], alone[:, 3:])  # the base, frame for frame
    assert np.abs(composed[:, :3] - alone[:, :3]).max() > 100  # the layer's pass differs
    np.testing.assert_array_equal(raw, alone)  # muted: the base plays through it
    t = np.arange(len(composed)) / FPS
    np.testing.assert_allclose(composed[:, :3], _motion([1, 2, 3], t, 1.0), atol=40)


def test_punch_seams_blend_without_a_pop(tmp_path, rig):
    base = _write(tmp_path / "base.mcap", rig, 3.0, 0.0, start_ns=1_000_000_000)
    layer = _layer(tmp_path, rig, base, [4, 5], phase=np.pi, punch_in="1.0", punch_out="2.0")
    with TakeReader(layer) as reader:
        stack = compose(reader, rig.servo_map.ids)
    assert [s for s, _ in stack.seams] == [1.0, 2.0]
    frames = _ticks(_frames(layer, rig))[:, 3:5].astype(float)
    base_f = _ticks(_frames(base, rig))[:, 3:5].astype(float)
    t = np.arange(len(frames)) / FPS
    own = _motion([4, 5], t, np.pi).astype(float)
    np.testing.assert_array_equal(frames[t < 0.95], base_f[t < 0.95])
    np.testing.assert_array_equal(frames[t > 2.05], base_f[t > 2.05])
    step = np.abs(np.diff(frames, axis=0))
    median = np.median(np.abs(np.diff(np.vstack([base_f, own]), axis=0)), axis=0)
    # the seam's own jump: how much faster the composed joint moves than either pass there
    jump = step - np.maximum(np.abs(np.diff(base_f, axis=0)), np.abs(np.diff(own, axis=0)))
    gap = np.abs(own - base_f)[int(1.0 * FPS)]
    assert (gap > 5 * median).any(), (gap, median)  # a hard cut would pop
    assert (jump.max(axis=0) <= median).all(), (jump.max(axis=0), median)
    assert step.max() < gap.max()


def test_the_top_layer_wins_a_servo_two_layers_hold_and_says_so(tmp_path, rig):
    base = _write(tmp_path / "base.mcap", rig, 3.0, 0.0, start_ns=1_000_000_000)
    one = _layer(tmp_path, rig, base, [1, 2, 3], name="one.mcap", phase=1.0)
    two = tmp_path / "two.mcap"
    _write(two, rig, 3.0, 2.0, start_ns=9_000_000_000,
           layer=LayerRef.over(one, two, [2, 4], rig_name=rig.name), raw_other=100)
    with TakeReader(two) as reader:
        stack = compose(reader, rig.servo_map.ids)
    assert stack.held == {1: one, 2: two, 3: one, 4: two}
    said = [n for n in stack.notes if "top layer wins" in n]
    assert len(said) == 1 and "[2]" in said[0], stack.notes
    frames = _ticks(_frames(two, rig))
    t = np.arange(len(frames)) / FPS
    np.testing.assert_allclose(frames[:, [1, 3]], _motion([2, 4], t, 2.0), atol=40)
    np.testing.assert_allclose(frames[:, [0, 2]], _motion([1, 3], t, 1.0), atol=40)
    np.testing.assert_allclose(frames[:, 5:], _motion(rig.servo_map.ids[5:], t, 0.0), atol=40)
    solo = _ticks(_frames(two, rig, layers=LayerOptions(solo=str(one))))
    np.testing.assert_allclose(solo[:, [0, 1, 2]], _motion([1, 2, 3], t, 1.0), atol=40)
    np.testing.assert_allclose(solo[:, 3:], _motion(rig.servo_map.ids[3:], t, 0.0), atol=40)


def test_a_base_that_ends_first_holds_its_last_frame_said(tmp_path, rig):
    base = _write(tmp_path / "base.mcap", rig, 1.0, 0.0, start_ns=1_000_000_000)
    layer = _layer(tmp_path, rig, base, [1], seconds=2.0)
    playback = _frames(layer, rig)
    assert any("ends at 1.00 s, before the layer (2.00 s): the base holds its last frame" in n
               for n in playback.layer_notes), playback.layer_notes
    frames = _ticks(playback)
    last = _motion(rig.servo_map.ids, np.array([1.0]), 0.0)[0]
    np.testing.assert_array_equal(frames[-1, 1:], last[1:])
    np.testing.assert_array_equal(frames[int(1.5 * FPS), 1:], last[1:])


def test_a_layer_over_a_base_of_another_rig_is_refused_naming_both(tmp_path, rig):
    base = _write(tmp_path / "base.mcap", rig, 1.0, 0.0, start_ns=1, rig_name="dragon")
    layer = _layer(tmp_path, rig, base, [1])
    with TakeReader(layer) as reader, pytest.raises(TakeError) as err:
        compose(reader, rig.servo_map.ids)
    assert "'critter'" in str(err.value) and "'dragon'" in str(err.value), str(err.value)


def test_a_changed_or_missing_base_is_refused(tmp_path, rig):
    base = _write(tmp_path / "base.mcap", rig, 1.0, 0.0, start_ns=1)
    layer = _layer(tmp_path, rig, base, [1])
    base.write_bytes(base.read_bytes() + b"\0")
    with TakeReader(layer) as reader, pytest.raises(TakeError, match="changed since"):
        compose(reader, rig.servo_map.ids)
    base.unlink()
    with TakeReader(layer) as reader, pytest.raises(TakeError, match="is missing"):
        compose(reader, rig.servo_map.ids)


def test_a_punch_at_a_marker_and_a_bad_punch(tmp_path, rig):
    base = _write(tmp_path / "base.mcap", rig, 2.0, 0.0, start_ns=1)
    layer = _layer(tmp_path, rig, base, [1], punch_in="nowhere")
    with TakeReader(layer) as reader, pytest.raises(TakeError, match="punch in 'nowhere'"):
        compose(reader, rig.servo_map.ids)
    with TakeReader(layer) as reader:
        stack = compose(reader, rig.servo_map.ids,
                        LayerOptions(punch={str(layer): ("0.5", "")}))
    assert stack.seams[0][0] == 0.5
