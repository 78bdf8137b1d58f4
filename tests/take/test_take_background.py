"""BackgroundTakeWriter: the same take as TakeWriter, written on its own thread."""

import threading
import time

import numpy as np
import pytest

from puppet.take import BackgroundTakeWriter, TakeError, TakeReader


def test_background_roundtrip_copies_reused_buffers(tmp_path, kit):
    path = tmp_path / "bg.mcap"
    reused = kit.reading_at(0, 0)
    with BackgroundTakeWriter(kit.open_writer(path)) as w:
        for i in range(300):
            src = kit.reading_at(i, 0)
            reused.t_ns = 1_000 + i * 2_000_000
            reused.ticks[:] = src.ticks  # the caller refills one buffer every time
            reused.ok[:] = src.ok
            w.write(reused)
    r = TakeReader(path)
    assert len(r) == 300 and r.truncated is False
    for i, got in enumerate(r.readings()):
        want = kit.reading_at(i, 0)
        assert got.t_ns == 1_000 + i * 2_000_000
        np.testing.assert_array_equal(got.ticks, want.ticks)
        np.testing.assert_array_equal(got.ok, want.ok)


def test_writer_thread_error_reaches_the_caller(tmp_path, kit):
    path = tmp_path / "bg.mcap"
    w = BackgroundTakeWriter(kit.open_writer(path))
    w.write(kit.reading_at(0, 5_000))
    w.write(kit.reading_at(1, 4_000))  # goes backwards: the thread's TakeWriter refuses it
    deadline = time.monotonic() + 60
    with pytest.raises(TakeError, match="writer thread failed: reading t_ns 4000 is earlier"):
        while time.monotonic() < deadline:
            w.write(kit.reading_at(2, 6_000))
            time.sleep(0.001)
    with pytest.raises(TakeError, match="writer thread failed"):
        w.close()
    with pytest.raises(TakeError, match="after close"):
        w.write(kit.reading_at(3, 7_000))
    r = TakeReader(path)
    assert len(r) == 1 and r.truncated is False  # what came before the error is kept


def test_full_queue_refuses_instead_of_blocking(tmp_path, kit):
    path = tmp_path / "bg.mcap"
    inner = kit.open_writer(path)
    gate = threading.Event()
    real_write = inner.write

    def slow_write(reading):
        gate.wait()
        real_write(reading)

    inner.write = slow_write  # a disk that stalls
    w = BackgroundTakeWriter(inner, max_queue=2)
    w.write(kit.reading_at(0, 0))
    deadline = time.monotonic() + 60
    while not w._queue.empty() and time.monotonic() < deadline:
        time.sleep(0.001)  # the thread has taken reading 0 and waits in write()
    w.write(kit.reading_at(1, 1))
    w.write(kit.reading_at(2, 2))
    with pytest.raises(TakeError, match=r"queue is full \(2 readings\)"):
        w.write(kit.reading_at(3, 3))
    assert w.dropped == 1
    gate.set()
    w.close()
    assert [r.t_ns for r in TakeReader(path).readings()] == [0, 1, 2]


def test_close_cannot_hang_when_the_thread_meets_an_unexpected_error(tmp_path, kit):
    """A reading the writer cannot encode (t_ns None) raises inside the thread; with the queue
    full behind it, close() still returns, with a TakeError naming the take."""
    path = tmp_path / "bg.mcap"
    inner = kit.open_writer(path)
    w = BackgroundTakeWriter(inner, max_queue=3)
    w.write(kit.reading_at(0, 1_000))
    bad = kit.reading_at(1, 2_000)
    bad.t_ns = None
    w.write(bad)
    deadline = time.monotonic() + 30
    while w._error is None and time.monotonic() < deadline:
        time.sleep(0.001)
    assert isinstance(w._error, TypeError)
    for _ in range(3):  # what the loop had queued before it heard of the error
        w._queue.put_nowait(kit.reading_at(2, 3_000))
    errors = []

    def close():
        try:
            w.close()
        except TakeError as e:
            errors.append(e)

    closer = threading.Thread(target=close, daemon=True)
    closer.start()
    closer.join(60)
    assert not closer.is_alive()
    assert len(errors) == 1
    assert str(path) in str(errors[0]) and "TypeError" in str(errors[0])
    assert "the 1 readings written before it are kept" in str(errors[0])
    r = TakeReader(path)
    assert [g.t_ns for g in r.readings()] == [1_000] and r.truncated is False
