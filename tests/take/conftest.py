"""Shared helpers for the take tests: a deterministic performance and a take writer."""

from types import SimpleNamespace

import numpy as np
import pytest

from puppet.reading import Reading
from puppet.take import TakeWriter

IDS = np.array([3, 7, 11, 12], dtype=np.int64)
MODELS = {3: "XL430-W250", 7: "XL430-W250", 11: "XM430-W350", 12: "XL330-M288"}
RIG_MAP = '[rig]\nname = "bench"\n[[servo]]\nid = 3\njoint = "neck"\naxis = "x"\n'
CALIBRATION = "[zero]\n3 = 2048\n7 = 1900\n11 = -4000\n12 = 77\n"


def reading_at(i: int, t_ns: int) -> Reading:
    """Reading number i of the test performance: ticks and ok are a function of i."""
    ticks = np.array([i, -3 * i, 4096 * i - 5, (i * 7919) % 100003 - 50000], dtype=np.int32)
    ok = np.array([True, i % 3 != 0, i % 5 != 1, i % 7 != 2])
    return Reading(t_ns=t_ns, ids=IDS, ticks=ticks, ok=ok)


def open_writer(path, **kw) -> TakeWriter:
    return TakeWriter(
        path, ids=IDS, models=MODELS, rig_map_text=RIG_MAP, calibration_text=CALIBRATION,
        rig_name="bench", **kw,
    )


@pytest.fixture
def kit():
    """The test performance's constants and helpers (tests import nothing from conftest)."""
    return SimpleNamespace(
        IDS=IDS, MODELS=MODELS, RIG_MAP=RIG_MAP, CALIBRATION=CALIBRATION,
        reading_at=reading_at, open_writer=open_writer,
    )


@pytest.fixture
def take_path(tmp_path):
    """A cleanly closed take of 200 readings at 500 Hz with 100 ns of jitter."""
    path = tmp_path / "take.mcap"
    with open_writer(path) as w:
        for i in range(200):
            w.write(reading_at(i, 10_000_000 + i * 2_000_000 + (i * 37) % 100))
    return path


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs folder (a disk that fills up); skipped where mounting is not allowed."""
    import subprocess

    folder = tmp_path / "disk"
    folder.mkdir()
    try:
        result = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(folder)],
                                capture_output=True, text=True, timeout=60)
    except FileNotFoundError:
        pytest.skip("no mount command on this machine: cannot make a small disk")
    if result.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (needs root or CAP_SYS_ADMIN): "
                    f"{result.stderr.strip()}")
    yield folder
    subprocess.run(["umount", "-l", str(folder)], check=True, timeout=60)
