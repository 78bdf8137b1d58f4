"""Shared helpers of the studio tests: real takes recorded into a session folder, and small
disks (tmpfs) that can be made read-only or full."""

import subprocess
from types import SimpleNamespace

import numpy as np
import pytest

from puppet.reading import Reading
from puppet.take import TakeWriter

IDS = np.array([3, 7, 11], dtype=np.int64)
MODELS = {3: "XL430-W250", 7: "XL430-W250", 11: "XM430-W350"}


def write_take(path, readings=31, rate_hz=30.0, rig_name="bench", ids=IDS, models=MODELS,
               zero=None, seed=0, layer=None, timecode=None):
    """A take of ``readings`` readings at ``rate_hz`` (its duration: (readings - 1) / rate_hz);
    ticks move around ``zero`` (default 2048); layer: its layer record (a LayerRef), if any;
    timecode: its start timecode (a StartTimecode: the rate it was recorded at), if any."""
    ids = np.asarray(ids)
    k = len(ids)
    zero = np.full(k, 2048) if zero is None else np.asarray(zero)
    with TakeWriter(path, ids=ids, models=models, rig_map_text="", calibration_text="",
                    rig_name=rig_name, layer=layer, timecode=timecode) as writer:
        for i in range(readings):
            ticks = (zero + 300 * np.sin(0.2 * i + seed + np.arange(k))).astype(np.int32)
            writer.write(Reading(1_000_000_000 + round(i * 1e9 / rate_hz), ids, ticks,
                                 np.ones(k, bool)))
    return path


def record(session, readings=31, **kw):
    """Record a take as a studio does: the path the session gives, the take, then listed."""
    path = session.new_take_path()
    write_take(path, readings, **kw)
    return session.add_take(path)


@pytest.fixture
def kit():
    return SimpleNamespace(write_take=write_take, record=record)


def _mount(folder, options):
    try:
        result = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)],
                                capture_output=True, text=True, timeout=60)
    except FileNotFoundError:
        pytest.skip("no mount command on this machine: cannot make a small disk")
    if result.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root or CAP_SYS_ADMIN): "
                    f"{result.stderr.strip()}")


@pytest.fixture
def tmpfs(tmp_path):
    """make(name, size) -> a folder on a new tmpfs of ``size`` ('256k', '64m'); remount(folder,
    'ro' | 'rw') turns it read-only or back; each is unmounted at the end."""
    mounted = []

    def make(name, size):
        folder = tmp_path / name
        folder.mkdir()
        _mount(folder, f"size={size}")
        mounted.append(folder)
        return folder

    def remount(folder, mode):
        subprocess.run(["mount", "-o", f"remount,{mode}", str(folder)], check=True, timeout=60)

    yield SimpleNamespace(make=make, remount=remount)
    for folder in reversed(mounted):
        subprocess.run(["umount", "-l", str(folder)], check=True, timeout=60)
