"""Benchmark: writing and reading takes (format 2, checksummed) against a baseline revision.

Cases: a take of N readings of 15 servos: TakeWriter.write per reading, TakeReader open (the
scan that checks every record) per reading, arrays() and readings() per reading.

Baseline (same run): the same measurements on the puppet package of another git revision
(``--baseline REV``, default the commit before take format 2), unpacked with ``git archive``
into a temporary folder and run in a child process. ``ratio`` = this tree / baseline (median of
``--repeat`` runs each). On a shared machine only the ratios mean something.

Usage: python bench/take_io.py [--json FILE] [--readings N] [--repeat R] [--baseline REV]
JSON: {"readings", "cases": [{"case", "us_per_reading", "baseline_us_per_reading", "ratio"}]}
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CASES = ("write", "open", "arrays", "readings")

CHILD = r'''
import json, os, sys, time
root, n, path = sys.argv[1], int(sys.argv[2]), sys.argv[3]
if root:
    sys.path.insert(0, root)
    sys.meta_path = [f for f in sys.meta_path if "editable" not in type(f).__module__.lower()]
import numpy as np
import puppet.take as take
assert not root or take.__file__.startswith(root), take.__file__
from puppet.reading import Reading
k = 15
ids = np.arange(1, k + 1)
ticks, ok = np.zeros(k, np.int32), np.ones(k, bool)
w = take.TakeWriter(path, ids=ids, models={int(i): "XL430-W250" for i in ids}, rig_map_text="",
                    calibration_text="", rig_name="bench", fsync_interval_s=None)
t = time.perf_counter()
for i in range(n):
    ticks[:] = i
    w.write(Reading(i * 2_000_000, ids, ticks, ok))
w.close()
out = {"write": time.perf_counter() - t}
t = time.perf_counter(); r = take.TakeReader(path); out["open"] = time.perf_counter() - t
assert len(r) == n
t = time.perf_counter(); r.arrays(); out["arrays"] = time.perf_counter() - t
t = time.perf_counter(); sum(1 for _ in r.readings()); out["readings"] = time.perf_counter() - t
os.remove(path)
print(json.dumps({c: s / n * 1e6 for c, s in out.items()}))
'''


def measure(root: str, n: int, folder: Path) -> dict[str, float]:
    """Microseconds per reading of every case, for the puppet package under root ("" = here)."""
    path = folder / f"take-{os.getpid()}.mcap"
    result = subprocess.run([sys.executable, "-c", CHILD, root, str(n), str(path)],
                            capture_output=True, text=True, check=True, cwd=folder)
    return json.loads(result.stdout)


def unpack(rev: str, folder: Path) -> Path:
    """The puppet package of git revision rev, unpacked under folder."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev, "puppet"],
                             capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(folder / "baseline", filter="data")
    return folder / "baseline"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None, help="write the results here")
    parser.add_argument("--readings", type=int, default=50_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--baseline", default="4994cae", help="git revision to compare with")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        base_root = str(unpack(args.baseline, folder))
        runs, base_runs = [], []
        start = time.monotonic()
        for _ in range(args.repeat):  # interleaved, so both see the same machine load
            runs.append(measure("", args.readings, folder))
            base_runs.append(measure(base_root, args.readings, folder))
    rows = []
    for case in CASES:
        here = statistics.median(r[case] for r in runs)
        base = statistics.median(r[case] for r in base_runs)
        rows.append({"case": case, "us_per_reading": round(here, 3),
                     "baseline_us_per_reading": round(base, 3), "ratio": round(here / base, 3)})
    print(f"{args.readings} readings of 15 servos, median of {args.repeat} "
          f"({time.monotonic() - start:.0f} s); baseline {args.baseline}")
    print(f"{'case':10s} {'us/reading':>11s} {'baseline':>9s} {'ratio':>6s}")
    for row in rows:
        print(f"{row['case']:10s} {row['us_per_reading']:11.2f} "
              f"{row['baseline_us_per_reading']:9.2f} {row['ratio']:6.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"readings": args.readings, "cases": rows}, indent=1))


if __name__ == "__main__":
    main()
