"""What the layer tests read from a recorded layer: its lag behind its base, and its raw readings
as a plain take (shared by tests/layers and the studio's page test)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from puppet.reading import Reading
from puppet.take import TakeReader, TakeWriter


def lag_s(base: Path, layer: Path, servo: int, settle_s: float) -> tuple[float, float, float]:
    """(lag s, its RMS ticks, the RMS ticks 1 s late): the shift of the layer's raw readings of
    ``servo`` (driven to the base) against the base's that fits best, both on their take time
    (time 0: first reading); the layer's first ``settle_s`` (the gentle start) left out."""
    with TakeReader(base) as reader:
        bt, bticks, _ = reader.arrays()
        col = list(reader.metadata.ids).index(servo)
        b_t, b = (bt - bt[0]) / 1e9, bticks[:, col].astype(float)
    with TakeReader(layer) as reader:
        lt, lticks, _ = reader.arrays()
        l_t, lay = (lt - lt[0]) / 1e9, lticks[:, col].astype(float)
    keep = (l_t > settle_s) & (l_t < b_t[-1] - 0.3)  # while the base plays
    fits = {round(d, 2): float(np.sqrt(np.mean((lay[keep] - np.interp(l_t[keep] - d, b_t, b)) ** 2)))
            for d in np.arange(-0.6, 1.21, 0.01)}
    lag = min(fits, key=fits.get)
    return lag, fits[lag], fits[1.0]


def raw_copy(layer: Path, path: Path) -> Path:
    """The layer's raw readings as a plain take (what the bus read in its pass; the layer
    dropped from its stack)."""
    with TakeReader(layer) as reader:
        m = reader.metadata
        t, ticks, ok = reader.arrays()
        with TakeWriter(path, ids=m.ids, models=m.models, rig_map_text=m.rig_map_text,
                        calibration_text=m.calibration_text, rig_name=m.rig_name) as w:
            for r in range(len(t)):
                w.write(Reading(int(t[r]), m.ids, ticks[r], ok[r]))
    return path
