"""A full disk while recording is a TakeError naming the take; every reading written before it
stays readable."""

import errno
import os
import time

import pytest

from puppet.take import BackgroundTakeWriter, TakeError, TakeReader


def t_of(i: int) -> int:
    return 1_000 + i * 2_000_000


def assert_prefix(path, kit, n):
    r = TakeReader(path)
    assert r.truncated is True
    got = list(r.readings())
    assert len(got) == n
    for i, g in enumerate(got):
        assert g.t_ns == t_of(i)
        assert g.ticks.tolist() == kit.reading_at(i, 0).ticks.tolist()
        assert g.ok.tolist() == kit.reading_at(i, 0).ok.tolist()


def test_full_disk_ends_the_take_cleanly(small_disk, kit):
    path = small_disk / "take.mcap"
    w = kit.open_writer(path)
    with pytest.raises(TakeError) as e:
        for i in range(100_000):
            w.write(kit.reading_at(i, t_of(i)))
    assert e.value.path == str(path)
    assert "the disk is full" in e.value.reason
    assert f"the {w.count} readings before it are kept" in e.value.reason
    assert w.count > 100
    with pytest.raises(TakeError, match="after a failed write"):
        w.write(kit.reading_at(w.count, t_of(w.count)))
    w.close()  # only closes the file: the error was reported once
    assert_prefix(path, kit, w.count)


def test_full_disk_in_the_background_writer(small_disk, kit):
    path = small_disk / "take.mcap"
    inner = kit.open_writer(path)
    w = BackgroundTakeWriter(inner)
    deadline = time.monotonic() + 60
    with pytest.raises(TakeError) as e:
        i = 0
        while time.monotonic() < deadline:
            w.write(kit.reading_at(i, t_of(i)))
            i += 1
            if i % 200 == 0:
                time.sleep(0.001)  # let the writer thread run
    assert "take writer thread failed" in str(e.value) and "the disk is full" in str(e.value)
    assert str(path) in str(e.value)
    with pytest.raises(TakeError, match="the disk is full"):
        w.close()
    assert_prefix(path, kit, inner.count)


def test_no_room_for_the_header_leaves_no_file(small_disk, kit):
    fd = os.open(small_disk / "filler", os.O_WRONLY | os.O_CREAT)
    with pytest.raises(OSError) as full:
        while True:
            os.write(fd, b"\0" * 512)
    os.close(fd)
    assert full.value.errno == errno.ENOSPC
    path = small_disk / "take.mcap"
    with pytest.raises(TakeError) as e:
        kit.open_writer(path)
    assert e.value.path == str(path) and "the disk is full" in e.value.reason
    assert not path.exists()
