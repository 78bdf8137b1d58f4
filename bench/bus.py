"""Benchmark: round trip of a group sync read and a fast sync read on the simulated bus.

Cases: 3 / 12 / 30 servos x read sync|fast x (timing model off; on at 1 Mbps; on at 4 Mbps).
Times ``GroupSyncRead.txRxPacket()`` / ``fastSyncRead()`` of Present Position (4 bytes) with the
unmodified dynamixel_sdk on hw_sim's pty. With the timing model on, Return Delay Time is 0
(the recommended setting; the model default 500 us would add 0.5 ms per servo).

Baseline (same run): a canned responder, a forked process that answers every instruction with
precomputed bytes: the floor for this pty + SDK + machine. ``ratio`` = hw_sim / baseline median.

If bench/bus_reader.py exists, its ``reader_cases() -> list[dict]`` cases ("read": "reader")
are appended to the table and the JSON.

Usage: python bench/bus.py [--json FILE] [--iterations N] [--no-reader]
JSON: {"cases": [{"servos", "read", "timing", "baud", "median_ms", "p99_ms", "reads_per_s"}],
       "baseline": [{"servos", "read", "median_ms", "p99_ms"}]}
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import pty
import statistics
import sys
import time
import tty
from pathlib import Path

import dynamixel_sdk as dxl

import hw_sim
from hw_sim import codec
from hw_sim.codec import InstructionParser

PRESENT_POSITION = 132
SERVO_COUNTS = (3, 12, 30)
READS = ("sync", "fast")
TIMINGS = ((False, 1_000_000), (True, 1_000_000), (True, 4_000_000))


def _time_reads(path: str, ids: list[int], read: str, baud: int, iterations: int) -> dict:
    port = dxl.PortHandler(path)
    assert port.openPort() and port.setBaudRate(baud)
    packet = dxl.PacketHandler(2.0)
    group = dxl.GroupSyncRead(port, packet, PRESENT_POSITION, 4)
    for i in ids:
        group.addParam(i)
    call = group.fastSyncRead if read == "fast" else group.txRxPacket
    for _ in range(max(10, iterations // 10)):
        call()
    samples, failures = [], 0
    for _ in range(iterations):
        t = time.perf_counter()
        result = call()
        samples.append(time.perf_counter() - t)
        failures += result != dxl.COMM_SUCCESS
    port.closePort()
    samples.sort()
    median = statistics.median(samples)
    return {"median_ms": median * 1e3,
            "p99_ms": samples[min(len(samples) - 1, int(0.99 * len(samples)))] * 1e3,
            "reads_per_s": 1.0 / median, "failures": failures}


def _canned_responder(ids: list[int]) -> tuple[str, int]:
    """Fork a minimal responder answering sync / fast sync reads with fixed bytes."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    data = (2048).to_bytes(4, "little")
    replies = {codec.SYNC_READ: b"".join(codec.status_packet(i, 0, data) for i in ids),
               codec.FAST_SYNC_READ: codec.fast_status_packet([(0, i, data) for i in ids])}
    pid = os.fork()
    if pid == 0:
        parser = InstructionParser()
        try:
            while True:
                chunk = os.read(master, 4096)
                if not chunk:
                    break
                for ins in parser.feed(chunk):
                    reply = replies.get(ins.inst)
                    if reply:
                        os.write(master, reply)
        finally:
            os._exit(0)
    os.close(master)
    return path, pid, slave


def run_cases(iterations: int) -> tuple[list[dict], list[dict]]:
    cases, baseline = [], []
    for n in SERVO_COUNTS:
        ids = list(range(1, n + 1))
        path, pid, slave = _canned_responder(ids)
        for read in READS:
            r = _time_reads(path, ids, read, 1_000_000, iterations)
            baseline.append({"servos": n, "read": read, "median_ms": r["median_ms"],
                             "p99_ms": r["p99_ms"]})
        os.close(slave)
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        for timing, baud in TIMINGS:
            with hw_sim.serve(ids, timing=timing, baud=baud, return_delay_us=0) as bus:
                for read in READS:
                    r = _time_reads(bus.port, ids, read, baud, iterations)
                    cases.append({"servos": n, "read": read, "timing": timing, "baud": baud,
                                  **r})
    return cases, baseline


def _reader_cases() -> list[dict]:
    path = Path(__file__).with_name("bus_reader.py")
    if not path.exists():
        return []
    spec = importlib.util.spec_from_file_location("bench_bus_reader", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return list(module.reader_cases())


def _report(cases: list[dict], baseline: list[dict], json_path: str | None,
            rows: list[dict] | None = None) -> None:
    """Print ``rows`` (default: all cases) as a table and write every case to ``json_path``."""
    base = {(b["servos"], b["read"]): b["median_ms"] for b in baseline}
    print(f"{'servos':>6} {'read':>6} {'timing':>6} {'baud':>9} {'median_ms':>10} {'p99_ms':>8} "
          f"{'reads/s':>8} {'canned_ms':>9} {'ratio':>6} {'fail':>4}")
    for c in cases if rows is None else rows:
        b = base.get((c["servos"], c["read"])) if not c.get("timing") else None
        canned = f"{b:.3f}" if b else "-"
        ratio = f"{c['median_ms'] / b:.2f}" if b else "-"
        print(f"{c['servos']:>6} {c['read']:>6} {str(c['timing']):>6} {c['baud']:>9} "
              f"{c['median_ms']:>10.3f} {c['p99_ms']:>8.3f} {c['reads_per_s']:>8.0f} "
              f"{canned:>9} {ratio:>6} {c.get('failures', '-'):>4}")
    if json_path:
        keys = ("servos", "read", "timing", "baud", "median_ms", "p99_ms", "reads_per_s")
        out = {"cases": [{k: c[k] for k in keys} for c in cases], "baseline": baseline}
        Path(json_path).write_text(json.dumps(out, indent=2) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", default=None, help="write results to this JSON file")
    parser.add_argument("--iterations", type=int, default=300, help="reads per case")
    parser.add_argument("--no-reader", action="store_true",
                        help="skip bench/bus_reader.py's cases even if it exists")
    args = parser.parse_args(argv)
    cases, baseline = run_cases(args.iterations)
    _report(cases, baseline, args.json)  # ours first: a failing reader bench loses nothing
    reader = [] if args.no_reader else _reader_cases()
    if reader:
        print("bus_reader cases (bench/bus_reader.py):")
        _report(cases + reader, baseline, args.json, rows=reader)
    return 0


if __name__ == "__main__":
    sys.exit(main())
