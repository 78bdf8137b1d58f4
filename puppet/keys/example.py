"""The built-in critter's example shot: four key poses a puppeteer might hold (a wave, a crouch,
a look round), used by ``bench/keys.py`` and the tests."""

from __future__ import annotations

import numpy as np

from puppet.take.keys import Key, Keys

CRITTER_POSES_DEG = (
    {},                                                                     # rest
    {4: -80, 5: 60, 6: -70, 1: 25, 2: 50, 10: -40, 12: 60},                 # wave, look left
    {4: 60, 5: -50, 7: 70, 8: 50, 10: -80, 11: 30, 12: 85, 13: -80, 14: -30, 15: 85, 3: -30},
    {2: -60, 3: 30, 7: -90, 8: -60, 9: -80, 13: -30, 15: 40},               # look right, reach
)
"""Per key: servo id -> joint angle, degrees (servos not named are at rest)."""


def critter_keys(rig, *, step: int = 12, fps: float = 24.0, interpolation: str = "linear") -> Keys:
    """The example shot's keys for ``rig`` (the built-in critter, calibrated): key i at frame
    1 + i·step, ticks from CRITTER_POSES_DEG through the rig's servo units."""
    ids = [int(i) for i in rig.servo_map.ids]
    keys = []
    for i, pose in enumerate(CRITTER_POSES_DEG):
        angles = np.radians([float(pose.get(sid, 0.0)) for sid in ids])
        keys.append(Key(1 + i * step, rig.servo_map.ticks_for(angles),
                        np.ones(len(ids), bool), interpolation))
    return Keys(float(fps), keys)
