"""Benchmark: the bus reader thread's sustained readings per second on hw_sim (timing model on).

For 14 servos at 1 Mbps and 4 Mbps it runs ``ReaderThread`` back to back (no rate limit) for a
few seconds and reports readings per second and the median / p99 interval between readings.
Baseline, measured in the same run on the same simulated bus once the reader has configured it:
a bare SDK ``GroupSyncRead`` loop (``fastSyncRead`` or ``txRxPacket``, the reader's read mode;
no fault handling, no unwrap, no thread); ``ratio`` = reader / baseline.
Target: reads_per_s >= 300 at 1 Mbps.

Protocol 1.0 cases: 15 AX-12A (one Read per servo) and 15 MX-28 (one Bulk Read) at 1 Mbps; the
SDK has no group read for them to compare with, so their baseline is the wire ceiling, the
bytes of one reading on the line (``wire_ceiling``), and ``ratio`` = reader / ceiling.

    python bench/bus_reader.py [--seconds 3] [--json FILE]

``bench/bus.py`` imports ``reader_cases()`` and appends its cases.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

SERVOS = 14
MODEL = "XL330-M288"
TARGET_READS_PER_S = 300.0


def _baseline(port_name: str, baud: int, seconds: float, fast: bool) -> float:
    """Reads per second of a bare SDK GroupSyncRead loop (``fastSyncRead`` when ``fast``) on
    the same bus, after the reader configured it (return delay 0)."""
    import dynamixel_sdk

    port = dynamixel_sdk.PortHandler(port_name)
    port.openPort()
    port.setBaudRate(baud)
    ph = dynamixel_sdk.PacketHandler(2.0)
    group = dynamixel_sdk.GroupSyncRead(port, ph, 132, 4)
    for i in range(1, SERVOS + 1):
        group.addParam(i)
    n = 0
    end = time.perf_counter() + seconds
    step = group.fastSyncRead if fast else group.txRxPacket
    while time.perf_counter() < end:
        step()
        n += 1
    rate = n / seconds
    port.closePort()
    return rate


def wire_ceiling(model: str, n: int, baud: int) -> float:
    """Readings per second the line allows for ``n`` servos of a Protocol 1.0 ``model`` (bits at
    ``baud``, 10 per byte; no return delay): AX / RX one Read each (8-byte instruction, 8-byte
    status: 2 bytes of Present Position), MX one Bulk Read (7 + 3n bytes) and n 8-byte statuses."""
    from puppet.servo_models import MODELS

    wire = 7 + 3 * n + 8 * n if MODELS[model].bulk_read else 16 * n
    return baud / 10.0 / wire


def measure(baud: int, seconds: float = 3.0, read_mode: str = "auto", model: str = MODEL,
            count: int = SERVOS) -> dict:
    """One case: the reader thread on a simulated bus of ``count`` ``model`` servos with its
    timing model on."""
    import hw_sim

    from puppet.bus import ReaderThread, ServoReader
    from puppet.servo_models import MODELS

    servos = {i: model for i in range(1, count + 1)}
    with hw_sim.serve(servos=servos, motion="wave", timing=True, baud=baud) as bus:
        reader = ServoReader(bus.port, servos, baud=baud, read_mode=read_mode)
        reader.open()
        thread = ReaderThread(reader, rate_hz=None, queue_len=1 << 16)
        with thread:
            time.sleep(0.3)  # warm up
            thread.drain()
            t0 = time.monotonic_ns()
            time.sleep(seconds)
            readings = thread.drain()
            t1 = time.monotonic_ns()
        reader.close()
        p1 = MODELS[model].protocol == 1.0
        base_sync = None if p1 else _baseline(bus.port, baud, min(1.0, seconds), fast=False)
        base_fast = None if p1 else _baseline(bus.port, baud, min(1.0, seconds), fast=True)
    if p1:
        baseline = wire_ceiling(model, count, baud)
        what = f"wire ceiling ({reader.read_mode}, {count} {model}, no return delay)"
    else:
        baseline = base_fast if reader.read_mode == "fast_sync_read" else base_sync
        what = f"bare SDK GroupSyncRead loop ({reader.read_mode}), same bus and settings"
    stamps = np.array([r.t_ns for r in readings], dtype=np.int64)
    gaps_ms = np.diff(stamps) / 1e6
    ok = float(np.mean([r.ok.all() for r in readings])) if readings else 0.0
    rate = len(readings) / ((t1 - t0) / 1e9)
    return {
        "servos": count,
        "model": model,
        "read": "reader",
        "read_mode": reader.read_mode,
        "timing": True,
        "baud": baud,
        "median_ms": float(np.median(gaps_ms)) if gaps_ms.size else float("nan"),
        "p99_ms": float(np.percentile(gaps_ms, 99)) if gaps_ms.size else float("nan"),
        "reads_per_s": rate,
        "all_ok_fraction": ok,
        "baseline": what,
        "baseline_reads_per_s": baseline,
        "sdk_sync_read_per_s": base_sync,
        "sdk_fast_sync_read_per_s": base_fast,
        "ratio": rate / baseline if baseline else float("nan"),
        "target_reads_per_s": TARGET_READS_PER_S if baud == 1_000_000 and not p1 else None,
    }


def reader_cases(seconds: float = 3.0) -> list[dict]:
    """The reader-thread cases for bench/bus.py: 14 servos, timing on, 1 Mbps and 4 Mbps; then
    Protocol 1.0: 15 AX-12A and 15 MX-28 at 1 Mbps."""
    return ([measure(baud, seconds) for baud in (1_000_000, 4_000_000)]
            + [measure(1_000_000, seconds, model=m, count=15) for m in ("AX-12A", "MX-28")])


def print_table(cases: list[dict]) -> None:
    head = f"{'servos':>6} {'model':>10} {'baud':>9} {'mode':>16} {'reads/s':>9} {'median ms':>10} {'p99 ms':>8} " \
           f"{'all ok':>7} {'base/s':>10} {'ratio':>6} {'target':>7}"
    print(head)
    print("-" * len(head))
    for c in cases:
        target = c["target_reads_per_s"]
        verdict = "" if target is None else ("met" if c["reads_per_s"] >= target else "MISSED")
        print(f"{c['servos']:>6} {c['model']:>10} {c['baud']:>9} {c['read_mode']:>16} {c['reads_per_s']:>9.0f} "
              f"{c['median_ms']:>10.3f} {c['p99_ms']:>8.3f} {c['all_ok_fraction']:>7.3f} "
              f"{c['baseline_reads_per_s']:>10.0f} {c['ratio']:>6.2f} {verdict:>7}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="measuring time per case")
    parser.add_argument("--json", default=None, help="write the cases as JSON here")
    args = parser.parse_args(argv)
    cases = reader_cases(args.seconds)
    print_table(cases)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"benchmark": "bus_reader", "cases": cases}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
