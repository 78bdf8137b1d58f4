"""The live link without Blender: the wire protocol, and ``puppet play TAKE --link`` streaming
the glTF export's keys to plain Python clients (latest wins, tokens, acks, a taken port)."""

from __future__ import annotations

import importlib.util
import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest

from puppet.link import wire

HERE = Path(__file__).resolve().parent


def _load(name):
    spec = importlib.util.spec_from_file_location(f"link_test_{name}", HERE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


client_module, helpers = _load("client"), _load("helpers")
Client, Puppet, gltf_keys = client_module.Client, helpers.Puppet, helpers.gltf_keys


def test_a_frame_round_trips_through_the_wire_in_any_chunking():
    t = [(0.5, -1.25, 2.0), (1e-9, 3.0, -4.5)]
    q = [(0.0, 0.0, 0.0, 1.0), (0.5, 0.5, 0.5, 0.5)]
    v = [(1.0, 2.0, 3.0), (-1.5, 0.25, 8.0), (0.0, 0.0, 0.0)]
    stream = (wire.encode_json(wire.HELLO, {"protocol": wire.PROTOCOL, "joints": ["a", "b"]})
              + wire.encode_frame(7, 123456789, 0.25, t, q, v) + wire.encode_ack(7, 1.5)
              + wire.encode_frame(8, -5, 1.0, t, q))
    for chunk in (1, 3, 7, len(stream)):
        reader, got = wire.Reader(), []
        for start in range(0, len(stream), chunk):
            reader.feed(stream[start:start + chunk])
            got += [wire.decode(k, b) for k, b in reader.messages()]
        hello, frame, ack, bare = got
        assert hello == {"protocol": 2, "joints": ["a", "b"]}
        assert (frame.seq, frame.reading_ns, frame.take_s, frame.count) == (7, 123456789, 0.25, 2)
        assert frame.translations == tuple(x for p in t for x in p)
        assert frame.rotations == tuple(x for p in q for x in p)
        assert frame.vertices.tolist() == [x for p in v for x in p]
        assert ack == (7, 1.5)
        assert (bare.seq, bare.reading_ns, bare.vertices) == (8, -5, None)


def test_malformed_messages_are_refused_by_name():
    with pytest.raises(ValueError, match="does not hold 2 joints"):
        whole = wire.encode_frame(1, 0, 0.0, [(0, 0, 0)] * 2, [(0, 0, 0, 1)] * 2)
        wire.decode(wire.FRAME_KIND, whole[5:-8])
    with pytest.raises(ValueError, match="unknown message kind"):
        wire.decode(b"Z", b"")
    reader = wire.Reader(max_message=100)
    reader.feed(wire.LENGTH.pack(101) + b"F")
    with pytest.raises(wire.WireError, match="outside 1..100"):
        list(reader.messages())


def _start(take, argv, wait_until):
    puppet = Puppet(["play", take, "--link", *argv])
    port, token = puppet.listening(wait_until)
    return puppet, port, token


def test_play_streams_the_gltf_exports_keys_to_two_clients_latest_wins(
        take, exported, critter, wait_until, interrupt_and_wait):
    names = list(critter.skeleton.names)
    t_file, q_file = gltf_keys(exported["glb"], names)
    puppet, port, _ = _start(take, ["127.0.0.1:0", "--speed", "0.5"], wait_until)
    try:
        fast = Client(port)
        slow = Client(port)
        assert fast.first[0] == wire.HELLO and slow.first[0] == wire.HELLO
        hello = fast.first[1]
        assert (hello["protocol"], hello["joints"], hello["vertices"]) == (
            wire.PROTOCOL, names, len(critter.V))
        assert hello["parents"] == [int(p) for p in critter.skeleton.parents]
        assert hello["fps"] == 30.0  # the rate play hands out frames at (--fps, the export's)
        assert hello["armature"] == np.eye(4).reshape(16).tolist()  # the critter: no nodes above
        assert hello["sound"] is None  # a take recorded without sound
        fast_seqs, slow_seqs = [], []
        slow_first = slow.next()[1]  # then the slow client stops reading (and acking)
        while True:
            kind, frame = fast.next()
            if kind != wire.FRAME_KIND:
                break
            k = round(frame.take_s * 30.0)
            assert abs(frame.take_s * 30.0 - k) < 1e-9
            t = np.reshape(frame.translations, (-1, 3))
            q = np.reshape(frame.rotations, (-1, 4))
            assert np.abs(t - t_file[k]).max() < 1e-5, k
            same = np.minimum(np.abs(q - q_file[k]).max(1), np.abs(q + q_file[k]).max(1))
            assert same.max() < 1e-5, k  # q and -q: one rotation (the file keeps a hemisphere)
            assert not frame.recording  # a play records nothing
            fast_seqs.append(frame.seq)
            fast.ack(frame.seq)
        assert kind == wire.BYE and frame["reason"]
        assert fast_seqs == sorted(set(fast_seqs)) and len(fast_seqs) > 10
        # The slow client held at most the window of frames while the fast one went on; then
        # it gets the newest frame, not the backlog.
        while True:
            kind, frame = slow.next()
            if kind != wire.FRAME_KIND:
                break
            slow_seqs.append(frame.seq)
        assert len(slow_seqs) <= 2
        assert slow_first.seq < fast_seqs[-1]
        assert len(slow_seqs) + 1 < len(fast_seqs)
        assert puppet.proc.wait(timeout=120) == 0
        summary = "\n".join(puppet.out)
        assert "2 client(s)" in summary and "reading->applied median" in summary, summary
    finally:
        interrupt_and_wait(puppet.proc, read_stderr=False)


def test_play_names_the_takes_sound_in_the_hello_or_warns_once_when_it_is_missing(
        tmp_path, critter, wait_until, interrupt_and_wait):
    """A take with a sound: the hello names its file (absolute) and offset; with the file gone,
    the hello has none and play says so once (Blender keys it silent)."""
    import soundfile as sf

    from puppet.sound import load_sound, sound_ref

    spec = importlib.util.spec_from_file_location("link_test_export_data_sound",
                                                  HERE.parent / "export" / "conftest.py")
    export_data = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(export_data)
    sound = tmp_path / "line.wav"
    sf.write(sound, np.zeros((8000, 1), np.float32), 8000)
    take = export_data.write_take(tmp_path / "voiced.mcap", critter, readings=10,
                                  sound=sound_ref(load_sound(sound), offset_s=0.25))
    for present in (True, False):
        if not present:
            sound.unlink()
        puppet, port, _ = _start(take, ["127.0.0.1:0"], wait_until)
        try:
            hello = Client(port).first[1]
            expected = {"path": str(sound.absolute()), "offset_s": 0.25} if present else None
            assert hello["sound"] == expected, hello["sound"]
            assert puppet.proc.wait(timeout=120) == 0, "\n".join(puppet.lines)
            warned = [x for x in puppet.lines if "line.wav" in x and "playing silent" in x]
            assert len(warned) == (0 if present else 1), puppet.lines
        finally:
            interrupt_and_wait(puppet.proc, read_stderr=False)


def test_a_recording_client_gets_every_frame_in_order_through_a_stall(
        take, wait_until, interrupt_and_wait):
    """A client that asks for every frame ("record") and stops reading for a while (a Blender
    stall) still gets each frame once, in order, when it reads again, and health messages say
    how puppet sees it; a latest-wins client beside it skips."""
    import time

    puppet, port, _ = _start(take, ["127.0.0.1:0", "--speed", "2"], wait_until)
    try:
        recorder = Client(port, record=True, health=True)
        plain = Client(port)
        assert recorder.first[0] == plain.first[0] == wire.HELLO
        assert recorder.first[1]["take"] == "take"  # the take's name: the action's
        time.sleep(1.0)  # the stall: puppet goes on publishing
        seqs, healths, plain_seqs = [], [], []
        while True:
            kind, message = recorder.next()
            if kind == wire.FRAME_KIND:
                seqs.append(message.seq)
                recorder.ack(message.seq)
            elif kind == wire.HEALTH:
                healths.append(message)
            else:
                break
        while True:
            kind, message = plain.next()
            if kind != wire.FRAME_KIND:
                break
            plain_seqs.append(message.seq)
        assert seqs == list(range(seqs[-1] + 1)), seqs  # every frame from the first, in order
        assert len(seqs) == 46  # the take's frames at 30 fps
        assert len(plain_seqs) < len(seqs)  # the one that did not read skipped
        assert healths and healths[-1]["lost"] == 0 and healths[-1]["skipped"] == 0
        assert healths[-1]["published"] >= healths[0]["published"]
        assert set(healths[-1]) == {"applied_median_ms", "applied_p99_ms", "acked", "published",
                                    "sent", "skipped", "lost", "acked_per_s"}
        assert puppet.proc.wait(timeout=120) == 0
    finally:
        interrupt_and_wait(puppet.proc, read_stderr=False)


def test_beyond_loopback_a_token_is_needed(take, wait_until, interrupt_and_wait):
    puppet, port, token = _start(take, ["0.0.0.0:0"], wait_until)
    try:
        assert token
        refused = Client(port, token="wrong")
        assert refused.first == (wire.ERROR,
                                 {"error": "token refused: give the token puppet printed"})
        assert refused.next() == (None, None)  # closed
        old = Client(port, token=token, protocol=99)
        assert old.first[0] == wire.ERROR and "protocol 99" in old.first[1]["error"]
        good = Client(port, token=token)
        assert good.first[0] == wire.HELLO
        kind, frame = good.next()
        assert kind == wire.FRAME_KIND and frame.seq == 0
    finally:
        interrupt_and_wait(puppet.proc, read_stderr=False)


def test_a_taken_port_is_an_error_naming_it(take):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        done = subprocess.run(["puppet", "play", str(take), "--link", str(port)],
                              capture_output=True, text=True, timeout=300)
    assert done.returncode == 1
    assert f"Error: --link: address 127.0.0.1:{port} is already in use" in done.stderr


def test_demo_streams_the_live_loop_with_reading_times(tmp_path, critter, wait_until,
                                                      interrupt_and_wait):
    puppet = Puppet(["demo", "--link", "127.0.0.1:0", "--seconds", "6", "--out",
                     tmp_path / "demo.mp4", "--size", "160", "120"])
    try:
        port, _ = puppet.listening(wait_until)
        live = Client(port)
        assert live.first[0] == wire.HELLO
        assert live.first[1]["joints"] == list(critter.skeleton.names)
        assert live.first[1]["fps"] == 60.0  # run_demo's loop target (late latching's rate)
        frames = []
        while True:
            kind, frame = live.next()
            if kind != wire.FRAME_KIND:
                break
            frames.append(frame)
            live.ack(frame.seq)
        assert kind == wire.BYE
        assert len(frames) >= 2
        seqs = [f.seq for f in frames]
        assert seqs == sorted(set(seqs))
        # the reading's time and the take time advance together (take time: since the first)
        reading_s = [(f.reading_ns - frames[0].reading_ns) * 1e-9 for f in frames]
        take_s = [f.take_s - frames[0].take_s for f in frames]
        assert np.allclose(reading_s, take_s, atol=1e-6)
        assert puppet.proc.wait(timeout=300) == 0
        assert any(line.startswith("link: 1 client(s)") for line in puppet.out), puppet.out
    finally:
        interrupt_and_wait(puppet.proc, read_stderr=False)


def test_demo_link_without_out_streams_and_writes_no_video(tmp_path):
    """``puppet demo --link`` without ``--out`` runs the loop for the link only: no video is
    encoded (``puppet demo`` alone writes demo.mp4 into the working folder), nothing is drawn."""
    done = subprocess.run(["puppet", "demo", "--link", "127.0.0.1:0", "--seconds", "2"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "link: listening on 127.0.0.1:" in done.stderr + done.stdout
    assert list(tmp_path.iterdir()) == []  # no demo.mp4
    assert "draw 0.0/0.0" in done.stdout, done.stdout  # nothing rendered for a video


def test_keys_streams_the_loop_it_shows_on_the_page(tmp_path, critter, wait_until,
                                                    interrupt_and_wait):
    """``puppet keys --view --link``: the capture's live loop goes to Blender as live does;
    without --view (no loop to stream) --link is refused before the bus."""
    import hw_sim
    from puppet.rig.load import BUILTIN_RIG

    refused = subprocess.run(["puppet", "keys", "--rig", str(BUILTIN_RIG), "--port", "no-port",
                              "--out", str(tmp_path / "s.mcap"), "--link", "127.0.0.1:0"],
                             capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2, refused.stderr
    assert "--link streams the live loop that --view runs: add --view" in refused.stderr
    with hw_sim.serve(critter.servo_map.models) as bus:
        puppet = Puppet(["keys", "--rig", BUILTIN_RIG, "--port", bus.port, "--out",
                         tmp_path / "shot.mcap", "--view", "127.0.0.1:0", "--link",
                         "127.0.0.1:0"], stdin=subprocess.PIPE)
        try:
            port, _ = puppet.listening(wait_until)
            live = Client(port)
            assert live.first[0] == wire.HELLO
            assert live.first[1]["joints"] == list(critter.skeleton.names)
            seqs = []
            while len(seqs) < 3:
                kind, frame = live.next()
                assert kind == wire.FRAME_KIND
                seqs.append(frame.seq)
                live.ack(frame.seq)
            assert seqs == sorted(set(seqs))
            puppet.proc.stdin.write("q\n")
            puppet.proc.stdin.flush()
            while kind == wire.FRAME_KIND:
                kind, _ = live.next()
            assert kind == wire.BYE
            assert puppet.proc.wait(timeout=300) == 0, "\n".join(puppet.lines)
            assert any(line.startswith("link: 1 client(s)") for line in puppet.out), puppet.out
        finally:
            interrupt_and_wait(puppet.proc, read_stderr=False)
