"""Layers benchmark against hw_sim (real SDK, its servo model and wire timing at 1 Mbps): a known
motion recorded in two passes (the legs, then the arms over the legs) against the same motion in
one pass.

The performer is hw_sim's motion source: every servo the puppeteer holds follows a known motion
M(p) of the take's play time p (p = 0 at the take's first reading, the base's clock in a layer:
the puppeteer performs with the base as a performer does). Pass 1 records the legs (arms held);
pass 2 records the arms with ``puppet live --over``'s parts (``BaseOverLive``, ``BaseDrive``,
``LayerTake``), the legs driven, torque on, to pass 1; the reference records both in one pass.

1. alignment: each servo of the layered shot (``Playback.of_take``, the one take-to-frames rule,
   at 30 fps) against the one pass's, lag by cross-correlation (sub-frame), over the whole take
   and over its first and last ``WINDOW_S``; target <= 1 frame.
2. tracking: the driven base servos' positions as read during pass 2 (the layer's raw readings)
   against the base's goal at the same play time, RMS degrees after the gentle start
   (``SETTLE_S``); target <= 2 degrees.
3. latency: from a base frame handed to the reader process to its goal written on the bus
   (``ReaderProcess.goal_delays_ms``), median and p99.

    python bench/layers.py --seconds 60 --json layers.json
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import hw_sim
from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_RIG
from puppet.session import Session
from puppet.session import layers
from puppet.session.outputs import Output, Take
from puppet.session.sources import BusSource
from puppet.take import Playback, TakeReader

ARMS = ("upperarm_L", "forearm_L", "upperarm_R", "forearm_R")
LEGS = ("thigh_L", "shin_L", "thigh_R", "shin_R")
FPS = 30.0
RATE_HZ = 500.0
WINDOW_S = 10.0
SETTLE_S = 3.0
AMPLITUDE_DEG = 25.0
PERIOD_S = 2.5
MAX_LAG_FRAMES = 6


class Performer:
    """hw_sim motion: servos ``ids`` follow M(p), p = monotonic now − ``start`` (a shared value set
    at the take's first reading; before it, M(0)); the others hold 2048."""

    def __init__(self, ids, start) -> None:
        self.ids, self.start = set(ids), start

    def position(self, joint: int, t: float) -> float:
        if joint not in self.ids:
            return 2048.0
        p = time.monotonic() - self.start.value if self.start.value else 0.0
        return 2048.0 + AMPLITUDE_DEG * 4096 / 360 * math.sin(2 * math.pi * p / PERIOD_S + joint)


class Clock(Output):
    """Sets the performer's time 0 at the take's first reading."""

    def __init__(self, start) -> None:
        self.start = start
        self.feed = self._feed

    def _feed(self, batch) -> None:
        if not self.start.value and batch:
            self.start.value = batch[0].t_ns * 1e-9


def _session(rig, source, outputs, seconds: float) -> Session:
    return Session(rig, source, outputs, seconds=seconds, solve=False, tell=lambda text: None,
                   say_setup=False)


def _record(rig, ids, path, seconds: float) -> None:
    start = multiprocessing.Value("d", 0.0, lock=False)
    with hw_sim.serve(dict(rig.servo_map.models), motion=Performer(ids, start), timing=True) as bus:
        _session(rig, BusSource(rig, bus.port, rate_hz=RATE_HZ),
                 [Take(path, rig), Clock(start)], seconds).run()


def _record_layer(rig, base, ids, path, seconds: float):
    start = multiprocessing.Value("d", 0.0, lock=False)
    plan = layers.LayerPlan.make(rig, base, joints=ARMS)
    with hw_sim.serve(dict(rig.servo_map.models), motion=Performer(ids, start), timing=True) as bus:
        _session(rig, layers.BaseOverLive(rig, bus.port, plan, rate_hz=RATE_HZ),
                 [layers.BaseDrive(plan, RATE_HZ, watchdog_ms=1000.0, tell=lambda text: None),
                  layers.LayerTake(path, plan), Clock(start)], seconds).run()
    return plan


def _frames(path, rig) -> np.ndarray:
    with TakeReader(path) as reader:
        return np.stack([r.ticks for r in Playback.of_take(reader, rig.servo_map.ids, fps=FPS)]
                        ).astype(float)


def _lag_frames(a: np.ndarray, b: np.ndarray) -> float:
    """Lag of ``a`` behind ``b`` in frames: the shift d (within +/- MAX_LAG_FRAMES, step 0.02)
    that brings b(f − d) nearest a(f), least squares over the frames both cover."""
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    if np.ptp(a) == 0 or np.ptp(b) == 0:
        return float("nan")
    f = np.arange(n, dtype=float)
    inner = (f >= MAX_LAG_FRAMES) & (f < n - MAX_LAG_FRAMES)
    shifts = np.arange(-MAX_LAG_FRAMES, MAX_LAG_FRAMES + 1e-9, 0.02)
    cost = [np.mean((a[inner] - np.interp(f[inner] - d, f, b)) ** 2) for d in shifts]
    return float(shifts[int(np.argmin(cost))])


def alignment(layered: np.ndarray, one: np.ndarray, cols) -> dict:
    """{whole, first, last}: the largest |lag| (frames) over servos ``cols``."""
    n = min(len(layered), len(one))
    w = int(WINDOW_S * FPS)
    parts = {"whole": slice(0, n), "first": slice(0, min(w, n)), "last": slice(max(0, n - w), n)}
    return {name: max(abs(_lag_frames(layered[s, c], one[s, c])) for c in cols)
            for name, s in parts.items()}


def tracking_deg(layer_path, plan) -> dict:
    """RMS and max degrees of the driven servos' read positions from the base's goals."""
    with TakeReader(layer_path) as reader:
        t, ticks, ok = reader.arrays(ids=plan.rig.servo_map.ids)
    play = (t - t[0]) * 1e-9
    keep = play >= SETTLE_S
    cols = plan.base_cols
    goals = np.stack([plan.goals.at(p)[cols].copy() for p in play[keep]])
    err = np.abs(ticks[keep][:, cols] - goals) * 360.0 / 4096.0  # X-series, gear 1 (critter)
    err = err[ok[keep][:, cols]]
    return {"rms_deg": float(np.sqrt(np.mean(err ** 2))), "max_deg": float(err.max()),
            "readings": int(keep.sum())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each pass")
    parser.add_argument("--json", default=None, help="write the figures here")
    args = parser.parse_args()
    rig = load_rig(BUILTIN_RIG)
    sm = rig.servo_map
    arm_ids = [int(s.id) for s in sm.servos if s.joint in ARMS]
    leg_ids = [int(s.id) for s in sm.servos if s.joint in LEGS]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        _record(rig, leg_ids, tmp / "legs.mcap", args.seconds)
        plan = _record_layer(rig, tmp / "legs.mcap", arm_ids, tmp / "arms.mcap", args.seconds)
        _record(rig, arm_ids + leg_ids, tmp / "one.mcap", args.seconds)
        layered, one = _frames(tmp / "arms.mcap", rig), _frames(tmp / "one.mcap", rig)
        ids = [int(i) for i in sm.ids]
        legs = alignment(layered, one, [ids.index(i) for i in leg_ids])
        arms = alignment(layered, one, [ids.index(i) for i in arm_ids])
        track = tracking_deg(tmp / "arms.mcap", plan)
    delays = plan.goal_delays_ms
    latency = {"median_ms": float(np.median(delays)), "p99_ms": float(np.percentile(delays, 99)),
               "samples": int(len(delays))}
    result = {"seconds": args.seconds, "fps": FPS, "baud": 1_000_000,
              "alignment_frames": {"legs": legs, "arms": arms}, "tracking": track,
              "base_frame_to_goal": latency}
    print(f"layers against hw_sim, {args.seconds:g} s passes, 1 Mbps, {len(sm.ids)} servos "
          f"(arms over legs vs one pass)")
    print(f"{'what':<34} {'whole':>8} {'first':>8} {'last':>8} {'target':>8}")
    for name, a in (("alignment legs, frames @30", legs), ("alignment arms, frames @30", arms)):
        print(f"{name:<34} {a['whole']:>8.2f} {a['first']:>8.2f} {a['last']:>8.2f} {'<= 1':>8}")
    print(f"{'driven base joints, RMS deg':<34} {track['rms_deg']:>8.2f} {'':>8} {'':>8} "
          f"{'<= 2':>8}   (max {track['max_deg']:.2f} deg)")
    print(f"{'base frame -> goal on bus, ms':<34} {latency['median_ms']:>8.2f} {'':>8} "
          f"{'':>8} {'':>8}   (median; p99 {latency['p99_ms']:.2f} ms)")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
