"""Benchmark: driving 15 servos on hw_sim (timing model on, Return Delay Time 0).

Cases: 1 Mbps and 4 Mbps. For each:
- ``cycle_hz``: free-running cycles of one goal Sync Write plus one (Fast) Sync Read of Moving ..
  Present Temperature (25 bytes, positions every cycle) of all servos, through puppet's
  DriveBus and the real dynamixel_sdk (1 / median cycle time);
- ``wire_ceiling_hz``: 1 / the bytes of those packets on the wire at that baud (10 bits a byte,
  no return delay, no USB latency): the physical ceiling; ``ratio`` = cycle_hz / ceiling;
- ``tracking_median_deg`` / ``tracking_p99_deg``: a 3 s take (every joint swinging 15 degrees)
  performed with the default options (100 Hz, default profile; Bus Watchdog 500 ms so that
  a stall of this shared machine does not trip it), present vs take, as
  ``perform`` reports it;
- ``sense_to_goal_median_ms`` / ``_p99_ms``: ``live``'s path with the built-in actuated-tail
  rig (critter_tail.toml: these 15 sensors plus one tail actuator) for ``--live-seconds``: the
  reader process, the solve, the goal channel; from a sensor reading's time stamp to the Sync
  Write of the tail goal solved from it (solve only, no render).

Figures on a shared machine vary with load; the ratio to the wire ceiling is the comparable one.

Usage: python bench/drive.py [--json FILE] [--iterations N]
JSON: {"cases": [{"servos", "baud", "read", "cycle_hz", "wire_ceiling_hz", "ratio",
       "tracking_median_deg", "tracking_p99_deg", "sense_to_goal_median_ms",
       "sense_to_goal_p99_ms", "read_failures"}]}
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import hw_sim
from puppet.bus.link import BusLink
from puppet.reading import Reading
from puppet.drive import PerformOptions, perform
from puppet.drive.items import StateLayout
from puppet.servo_models import X_ITEMS
from puppet.drive.servos import DriveBus
from puppet.bus.reader_process import ReaderProcess
from puppet.drive.actuators import ActuationPlan, ActuatorHook, LiveActuation
from puppet.loop import Pipeline, run_live
from puppet.rig import builtin, load_rig
from puppet.rig.calibration import Calibration
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader, TakeWriter

SERVOS = 15
BAUDS = (1_000_000, 4_000_000)


def wire_ceiling_hz(servos: int, baud: int, fast: bool,
                    read_bytes: int = StateLayout.of(X_ITEMS).block.size) -> float:
    """1 / wire time of one goal Sync Write + one (Fast) Sync Read and its replies."""
    sync_write = 14 + servos * (1 + 4)          # header..INST 8, addr 2, len 2, CRC 2
    sync_read = 14 + servos                     # same, plus one id per servo
    if fast:                                    # one packet: 8 + per servo ERR ID data CRC2
        replies = 8 + servos * (4 + read_bytes)
    else:                                       # one status per servo: 11 bytes + data
        replies = servos * (11 + read_bytes)
    return baud / (10.0 * (sync_write + sync_read + replies))


def _cycle(port: str, rig, baud: int, iterations: int) -> tuple[float, int]:
    ids = [int(i) for i in rig.servo_map.ids]
    link = BusLink(port, baud=baud, latency_ms=1)
    link.open()
    bus = DriveBus(link, ids, dict(rig.servo_map.models), log=lambda _l: None)
    bus.prepare(use_watchdog=False)  # finds the servos; Fast Sync Read where they have it
    goals = np.full(len(ids), 2048.0)
    samples, failures = [], 0
    try:
        for n in range(iterations + 50):
            t = time.perf_counter()
            bus.write_goals(goals)
            state = bus.read_state()
            dt = time.perf_counter() - t
            if n >= 50:
                samples.append(dt)
                failures += int((~state.ok).sum())
    finally:
        link.close()
    return 1.0 / statistics.median(samples), failures, bus.fast_read


def _wave_take(path: Path, rig) -> Path:
    ids = rig.servo_map.ids
    k = len(ids)
    calibration = Calibration.capture(ids, rig.servo_map.zero)
    with TakeWriter(path, ids=ids, models=dict(rig.servo_map.models), rig_map_text="",
                    calibration_text=calibration.to_record(), rig_name=rig.name,
                    overwrite=True) as writer:
        for n in range(300):
            t = n / 100.0
            angles = np.radians(15.0 * np.sin(2 * np.pi * 0.5 * t + np.arange(k)))
            writer.write(Reading(t_ns=int(t * 1e9), ids=ids,
                                 ticks=rig.servo_map.ticks_for(angles), ok=np.ones(k, bool)))
    return path


TAIL_RIG = BUILTIN_RIG.parent / "critter_tail.toml"


def _sense_to_goal(baud: int, seconds: float) -> tuple[float, float]:
    """(median, p99) ms from a sensor reading to its tail goal on the bus, in live's path."""
    rig = load_rig(TAIL_RIG)
    plan = ActuationPlan.for_rig(rig, 500.0, watchdog_ms=2000.0)
    actuation = LiveActuation(rig)
    with hw_sim.serve(dict(rig.servo_map.models), motion="wave", timing=True, baud=baud,
                      return_delay_us=0) as sim:
        source = ReaderProcess(sim.port, rig.servo_map.models, rate_hz=500.0, baud=baud,
                               latency_ms=1, hook=ActuatorHook(plan))
        source.start()
        actuation.source = source
        try:
            with Pipeline(rig, render=False) as pipeline:
                run_live(pipeline, source, seconds=seconds, after_solve=actuation.after_solve)
            delays = source.goal_delays_ms()
        finally:
            source.stop()
    return float(np.median(delays)), float(np.percentile(delays, 99))


def run_cases(iterations: int, live_seconds: float = 5.0) -> list[dict]:
    rig = builtin()
    models = dict(rig.servo_map.models)
    assert len(models) == SERVOS
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        take = _wave_take(Path(tmp) / "wave.mcap", rig)
        for baud in BAUDS:
            with hw_sim.serve(models, timing=True, baud=baud, return_delay_us=0) as sim:
                cycle_hz, failures, fast = _cycle(sim.port, rig, baud, iterations)
                report = perform(rig, TakeReader(take), sim.port,
                                 PerformOptions(yes=True, baud=baud, latency_ms=4,
                                                watchdog_ms=500.0))
            s2g_median, s2g_p99 = _sense_to_goal(baud, live_seconds)
            ceiling = wire_ceiling_hz(SERVOS, baud, fast)
            cases.append({"servos": SERVOS, "baud": baud, "read": "fast" if fast else "sync",
                          "cycle_hz": round(cycle_hz, 1),
                          "wire_ceiling_hz": round(ceiling, 1),
                          "ratio": round(cycle_hz / ceiling, 3),
                          "tracking_median_deg": round(report.tracking_median_deg, 3),
                          "tracking_p99_deg": round(report.tracking_p99_deg, 3),
                          "sense_to_goal_median_ms": round(s2g_median, 2),
                          "sense_to_goal_p99_ms": round(s2g_p99, 2),
                          "read_failures": failures})
    return cases


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", default=None, help="write results to this JSON file")
    parser.add_argument("--iterations", type=int, default=300, help="timed cycles per case")
    parser.add_argument("--live-seconds", type=float, default=5.0,
                        help="live run per case for the sense-to-goal delay")
    args = parser.parse_args(argv)
    cases = run_cases(args.iterations, args.live_seconds)
    print(f"{'servos':>6} {'baud':>9} {'cycle Hz':>9} {'ceiling Hz':>10} {'ratio':>6} "
          f"{'track med':>9} {'track p99':>9} {'s2g med':>8} {'s2g p99':>8} {'fails':>5}")
    for c in cases:
        print(f"{c['servos']:>6} {c['baud']:>9} {c['cycle_hz']:>9.1f} {c['wire_ceiling_hz']:>10.1f} "
              f"{c['ratio']:>6.3f} {c['tracking_median_deg']:>9.3f} {c['tracking_p99_deg']:>9.3f} "
              f"{c['sense_to_goal_median_ms']:>8.2f} {c['sense_to_goal_p99_ms']:>8.2f} "
              f"{c['read_failures']:>5}")
    if args.json:
        Path(args.json).write_text(json.dumps({"cases": cases}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
