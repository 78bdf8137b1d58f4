"""PC2 point caches: header fields and samples read back by an independent reader."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from puppet.export import ExportError, Pc2Writer, write_pc2

_spec = importlib.util.spec_from_file_location("export_pc2_readers", Path(__file__).with_name("readers.py"))
readers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readers)
read_pc2 = readers.read_pc2


def motion(num_samples, n=57, seed=3):
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(n, 3)).astype(np.float32)
    for s in range(num_samples):
        yield base + np.float32(0.01 * s) * base[::-1]


def test_write_pc2_roundtrip_and_header(tmp_path):
    path = tmp_path / "mesh.pc2"
    frames = list(motion(40))
    assert write_pc2(path, iter(frames), start_frame=12, sample_rate=0.5) == 40
    header, samples = read_pc2(path)
    assert header == dict(signature=b"POINTCACHE2\0", version=1, num_points=57, start_frame=12.0,
                          sample_rate=0.5, num_samples=40)
    np.testing.assert_array_equal(samples, np.stack(frames))


def test_streaming_writer_takes_any_float_layout(tmp_path):
    path = tmp_path / "s.pc2"
    pts = np.arange(30, dtype=np.float64).reshape(3, 10).T  # float64, Fortran order
    with Pc2Writer(path, 10) as w:
        w.write(pts)
        w.write(pts[::-1])
        assert w.num_samples == 2
    header, samples = read_pc2(path)
    assert header["num_samples"] == 2 and header["start_frame"] == 0.0
    assert header["sample_rate"] == 1.0
    np.testing.assert_array_equal(samples[0], pts.astype(np.float32))
    np.testing.assert_array_equal(samples[1], pts[::-1].astype(np.float32))


def test_header_patched_even_when_the_caller_fails(tmp_path):
    path = tmp_path / "partial.pc2"
    with pytest.raises(ExportError, match=r"sample 3: points have shape \(56, 3\)"):
        with Pc2Writer(path, 57) as w:
            for s, pts in enumerate(motion(10)):
                w.write(pts if s < 3 else pts[:56])
    header, samples = read_pc2(path)
    assert header["num_samples"] == 3
    np.testing.assert_array_equal(samples[2], list(motion(3))[2])


def test_bad_input(tmp_path):
    path = tmp_path / "bad.pc2"
    with pytest.raises(ExportError, match="no frames to write") as e:
        write_pc2(path, [])
    assert str(path) in str(e.value)
    with pytest.raises(ExportError, match=r"expected \(n, 3\)"):
        write_pc2(path, [np.zeros((4, 2), np.float32)])
    pts = np.zeros((5, 3), np.float32)
    pts[3, 1] = np.nan
    with pytest.raises(ExportError, match="sample 1: vertex 3 is not finite"):
        write_pc2(path, [np.zeros((5, 3), np.float32), pts])
    with pytest.raises(ExportError, match="sample_rate"):
        Pc2Writer(path, 5, sample_rate=0)
    with pytest.raises(ExportError, match="num_points must be >= 1"):
        Pc2Writer(path, 0)
    with pytest.raises(ExportError, match="cannot create point cache"):
        Pc2Writer(tmp_path / "missing" / "dir.pc2", 5)
    w = Pc2Writer(path, 5)
    w.close()
    with pytest.raises(ExportError, match="after close"):
        w.write(np.zeros((5, 3), np.float32))
