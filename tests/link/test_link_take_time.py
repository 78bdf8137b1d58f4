"""A live recording's frames on the link carry the take's outputs' time line: a bus stall
longer than MAX_GAP_S, which playback (and so ``puppet export``) cuts to MAX_GAP_S, is cut the
same way on the link, so Blender's keys after the stall land where the export puts them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.events import EventLog
from puppet.link import Link, wire
from puppet.loop import Pipeline
from puppet.loop.run import run_live
from puppet.session.outputs import _TakeFromZero
from puppet.take import MAX_GAP_S, TakeReader
from puppet.take.playback import PlayClock, play_times_ns

HERE = Path(__file__).resolve().parent
spec = importlib.util.spec_from_file_location("link_time_client", HERE / "client.py")
client_module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(client_module)


def test_the_play_clock_is_playbacks_rule_reading_by_reading():
    rng = np.random.default_rng(3)
    t_ns = np.cumsum(rng.choice([8_000_000, 2_500_000_000, 1_000_000_000, 0], 200, p=[.9, .04, .03, .03]))
    clock = PlayClock()
    assert [clock.advance(int(t)) for t in t_ns] == play_times_ns(t_ns)[0].tolist()


class _Readings:
    """The readings given, one a drain (each solved and streamed); then none, and ``done``."""

    def __init__(self, readings):
        self.readings = list(readings)
        self.done = False
        self.log = EventLog()

    def drain(self):
        if not self.readings:
            self.done = True
            return []
        return [self.readings.pop(0)]

    def latest(self, timeout=None):
        batch = self.drain()
        return batch[-1] if batch else None


def test_a_stall_while_recording_is_cut_on_the_link_as_in_the_take_outputs(tmp_path, critter):
    ids = critter.servo_map.ids
    k = len(ids)
    period_ns, stall_ns = 10_000_000, int(3.5 * MAX_GAP_S * 1e9)
    t_ns = [1_000_000_000 + i * period_ns + (stall_ns if i >= 20 else 0) for i in range(40)]
    readings = [Reading(t, ids, (critter.servo_map.zero + 40 * np.sin(0.2 * i + np.arange(k)))
                        .astype(np.int32), np.ones(k, bool)) for i, t in enumerate(t_ns)]
    source = _Readings(readings)
    path = tmp_path / "stall.mcap"
    recorder = _TakeFromZero(path, critter, force=False, zero_ns=t_ns[0], from_ns=t_ns[0])
    link = Link("127.0.0.1:0", critter, fps=30.0)
    with Pipeline(critter, render=False) as pipeline:
        link.attach(pipeline, fps=30.0)
        client = client_module.Client(link.port, record=True)
        try:
            assert client.first[0] == wire.HELLO
            run_live(pipeline, source, recorder=recorder, link=link, latch_fps=None,
                     should_stop=lambda: source.done)
            recorder.close()
            frames = []
            while len(frames) < len(readings):
                kind, message = client.next()
                assert kind is not None, f"the link closed after {len(frames)} frames"
                if kind == wire.FRAME_KIND:
                    assert message.flags & wire.RECORDING
                    frames.append(message)
                    client.ack(message.seq)
        finally:
            client.close()
            link.close()
    take = TakeReader(path)
    play_ns, cuts = play_times_ns(take.timestamps())
    assert len(cuts) == 1   # the stall, cut to MAX_GAP_S in every output
    assert [f.reading_ns for f in frames] == t_ns
    assert [f.take_s for f in frames] == pytest.approx(play_ns * 1e-9, abs=1e-9)
    assert frames[20].take_s - frames[19].take_s == pytest.approx(MAX_GAP_S)
