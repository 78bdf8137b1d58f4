"""Child process of the kill tests: records readings at about 500 Hz until it is killed.

usage: python take_crash_child.py TAKE [--background]
After each write() returns it prints "i t_ns" on stdout, so the parent knows what was written
(with --background: what was queued to a BackgroundTakeWriter). SIGTERM ends the recording
the way ``puppet record`` does: the loop stops, the take is closed, exit status 0.
Reading i has ticks [i, -3i, 4096i - 5, (7919 i mod 100003) - 50000] and ok all True.
"""

import signal
import sys
import time

import numpy as np

from puppet.reading import Reading
from puppet.take import BackgroundTakeWriter, TakeWriter

stop = []
signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
ids = np.array([3, 7, 11, 12])
models = {3: "XL430-W250", 7: "XL430-W250", 11: "XM430-W350", 12: "XL330-M288"}
writer = TakeWriter(
    sys.argv[1], ids=ids, models=models, rig_map_text="[rig]\n", calibration_text="[zero]\n",
    rig_name="crash",
)
if "--background" in sys.argv:
    writer = BackgroundTakeWriter(writer)
ok = np.ones(4, dtype=bool)
period_ns = 2_000_000
next_ns = time.monotonic_ns()
i = 0
while not stop:
    ticks = np.array([i, -3 * i, 4096 * i - 5, (i * 7919) % 100003 - 50000], dtype=np.int32)
    t_ns = time.monotonic_ns()
    writer.write(Reading(t_ns=t_ns, ids=ids, ticks=ticks, ok=ok))
    sys.stdout.write(f"{i} {t_ns}\n")
    sys.stdout.flush()
    i += 1
    next_ns += period_ns
    delay = next_ns - time.monotonic_ns()
    if delay > 0:
        time.sleep(delay * 1e-9)
writer.close()
