"""Benchmark: the Dynamixel bus on hw_sim, read through the unmodified dynamixel_sdk on a pty.

1. The bus at its limit (issue #28; ``family_cases``), timing model on, Return Delay Time 0,
   through puppet's own transactions (``BusLink.group_read``):
   - 15 X-series servos (XL430-W250), one Fast Sync Read of Present Position at 1, 2, 3 and 4
     Mbps: the bytes on the line for one reading (counted by hw_sim: 157), the wire time (10
     bits a byte), the ceiling (1 / wire time) and the measured readings per second against it
     (``ratio``; target >= 0.8);
   - 15 AX-12A at 1 Mbps, one READ per servo (AX has no Bulk Read), and 15 MX-28 at 1 Mbps, one
     Protocol 1.0 Bulk Read, each against its own ceiling;
   - a silent servo: a Fast Sync Read of those 15 plus one absent id with the SDK's deadline
     sized for a USB latency timer of 16 ms (Linux's FTDI default) and of 1 ms (what puppet
     sets), as ``puppet.bus.set_latency_assumption`` sets it; cost = that reading's median
     minus the clean one's, both measured in the same run (target <= 5 ms at 1 ms). hw_sim's
     pty has no USB latency of its own: this is the deadline the host waits out.
   The ceiling is the baseline of these cases: it is computed from the bytes counted in the
   same run. Beside each Fast Sync Read, the pseudo-terminal's own ceiling, measured right after
   (``_pty_round_trips``): the same bytes each way through a raw pty, answered when hw_sim's
   timing model would, no protocol. Its round trip minus the wire time is what the pty and the
   scheduler cost (about a tenth of a millisecond a round trip, whatever the baud: it weighs most
   at 4 Mbps, where the wire takes 0.39 ms);
   puppet's median minus the pty's is the protocol's share (the SDK's packet building and
   parsing, puppet's transaction, hw_sim's decoding). ``pty_ratio`` = pty ceiling / wire ceiling
   is the best any protocol could read at through this pty; ``ratio_to_pty`` = puppet's rate /
   the pty's.
2. Round trip of a group Sync Read and Fast Sync Read: 3 / 12 / 30 servos x read sync|fast x
   (timing model off; on at 1 Mbps; on at 4 Mbps), ``GroupSyncRead.txRxPacket()`` /
   ``fastSyncRead()`` of Present Position (4 bytes). Baseline (same run): a canned responder,
   a forked process that answers every instruction with precomputed bytes: the floor for this
   pty + SDK + machine. ``ratio`` = hw_sim / baseline median.

If bench/bus_reader.py exists, its ``reader_cases() -> list[dict]`` cases ("read": "reader")
are appended to the table and the JSON.

Usage: python bench/bus.py [--json FILE] [--iterations N] [--no-reader] [--families-only]
JSON: {"families": [{"case", "read", "model", "servos", "baud", "bytes", "wire_ms",
       "ceiling_per_s", "median_ms", "p99_ms", "reads_per_s", "ratio", "target", "failures"} and
       {"case", "latency_ms", "clean_ms", "median_ms", "silent_cost_ms", "sdk_deadline_ms",
       "target", ...}],
       "cases": [{"servos", "read", "timing", "baud", "median_ms", "p99_ms", "reads_per_s"}],
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
from puppet.bus import BusLink, set_latency_assumption
from puppet.servo_models import MODELS

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


# ---- the bus at its limit (issue #28): every family's fastest read against the wire ---------
FAMILY_SERVOS = 15
FAST_BAUDS = (1_000_000, 2_000_000, 3_000_000, 4_000_000)
X_MODEL = "XL430-W250"          # an X-series model whose Baud Rate reaches 4 Mbps
SILENT_LATENCIES_MS = (16, 1)   # Linux's FTDI default, and the latency timer puppet sets
TARGET_RATIO = 0.8              # measured rate / wire ceiling, with hw_sim's timing on
TARGET_SILENT_MS = 5.0          # a silent servo's cost with a 1 ms latency timer


def _time_family(path: str, baud: int, model: str, ids: list[int], read: str, iterations: int,
                 bus=None, latency_ms: int = 1) -> dict:
    """Median / p99 ms of one reading of Present Position of ``ids`` through puppet's own
    transactions (``BusLink.group_read``: "fast" one Fast Sync Read, "bulk" one Protocol 1.0 Bulk
    Read, "read" one READ per servo), with the SDK's latency assumption ``latency_ms``;
    failures; ``bytes``: bytes on hw_sim's line for one clean reading (host's and servos'),
    counted from ``bus.traffic()`` when ``bus`` is given (None if none of five was clean)."""
    item = MODELS[model].items.present_position
    link = BusLink(path, baud, latency_ms=latency_ms, protocol=MODELS[model].protocol)
    link.open()
    items = dict.fromkeys(ids, item)
    bulk = ids if read == "bulk" else ()

    def call() -> bool:
        return not link.group_read(items, fast=read == "fast", bulk=bulk).failed

    try:
        for _ in range(max(5, iterations // 10)):
            call()
        wire = host_bytes = None
        if bus is not None:  # the fewest of five clean readings: a late or retried exchange (a
            counted = []     # busy host) only adds bytes, to its own window or the next one
            for _ in range(5):
                bus.traffic()
                clean = call()
                traffic = bus.traffic()
                if clean:
                    counted.append((sum(len(data) for _, _, data in traffic),
                                    sum(len(data) for _, kind, data in traffic if kind == "rx")))
            wire, host_bytes = min(counted, default=(None, None))
        samples, failures = [], 0
        for _ in range(iterations):
            t = time.perf_counter()
            failures += not call()
            samples.append(time.perf_counter() - t)
    finally:
        link.close()
        set_latency_assumption(1)
    samples.sort()
    return {"median_ms": statistics.median(samples) * 1e3,
            "p99_ms": samples[min(len(samples) - 1, int(0.99 * len(samples)))] * 1e3,
            "failures": failures, "bytes": wire, "host_bytes": host_bytes}


def _pty_round_trips(host_bytes: int, servo_bytes: int, baud: int, iterations: int) -> dict:
    """The pseudo-terminal's own ceiling for one reading: raw bytes of the same sizes through the
    same kind of pty as hw_sim's (raw mode), no protocol. The host writes ``host_bytes`` and reads
    ``servo_bytes``; a forked responder reads the host's bytes and answers when hw_sim's timing
    model would (the host's bytes and the reply's on the line at 10 bits a byte from the moment it
    read them, sleeping then spinning the last 0.2 ms as hw_sim does). Median / p99 ms of the
    round trip: wire time + what the pty and the scheduler add, nothing else."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    byte_s = 10.0 / baud
    reply = bytes(range(256)) * (servo_bytes // 256 + 1)
    pid = os.fork()
    if pid == 0:
        try:
            os.close(slave)
            got = 0
            while True:
                chunk = os.read(master, 4096)
                if not chunk:
                    break
                t_rx = time.monotonic()
                got += len(chunk)
                if got < host_bytes:
                    continue
                got = 0
                turn = t_rx + (host_bytes + servo_bytes) * byte_s
                while (rem := turn - time.monotonic()) > 0:
                    if rem > 3e-4:
                        time.sleep(rem - 2e-4)
                os.write(master, reply[:servo_bytes])
        except OSError:
            pass
        finally:
            os._exit(0)
    os.close(master)
    request = b"\xff" * host_bytes
    samples = []
    try:
        for i in range(iterations + max(5, iterations // 10)):
            t = time.perf_counter()
            os.write(slave, request)
            need = servo_bytes
            while need > 0:
                need -= len(os.read(slave, need))
            if i >= max(5, iterations // 10):
                samples.append(time.perf_counter() - t)
    finally:
        os.close(slave)
        os.kill(pid, 9)
        os.waitpid(pid, 0)
    samples.sort()
    return {"median_ms": statistics.median(samples) * 1e3,
            "p99_ms": samples[min(len(samples) - 1, int(0.99 * len(samples)))] * 1e3}


def _time_sdk_fast(path: str, ids: list[int], latency_ms: int, iterations: int) -> float:
    """Median ms of the SDK's own ``fastSyncRead`` of Present Position (X-series) of ``ids``
    at 1 Mbps, its deadline sized for a ``latency_ms`` latency timer."""
    set_latency_assumption(latency_ms)
    port = dxl.PortHandler(path)
    assert port.openPort() and port.setBaudRate(1_000_000)
    group = dxl.GroupSyncRead(port, dxl.PacketHandler(2.0), PRESENT_POSITION, 4)
    for i in ids:
        group.addParam(i)
    samples = []
    try:
        for _ in range(iterations):
            t = time.perf_counter()
            group.fastSyncRead()
            samples.append(time.perf_counter() - t)
    finally:
        port.closePort()
        set_latency_assumption(1)
    return statistics.median(samples) * 1e3


def family_cases(iterations: int) -> list[dict]:
    """The issue's table: 15 X-series by Fast Sync Read at 1-4 Mbps, 15 AX-12A by one READ each
    and 15 MX-28 by one Bulk Read at 1 Mbps; each next to its wire ceiling (the bytes counted on
    the line, 10 bits each, no return delay) in the same run; and a silent servo's cost with the
    latency timer at 16 and 1 ms."""
    ids = list(range(1, FAMILY_SERVOS + 1))
    rows = []
    plan = [("fast", X_MODEL, baud) for baud in FAST_BAUDS]
    plan += [("read", "AX-12A", 1_000_000), ("bulk", "MX-28", 1_000_000)]
    for read, model, baud in plan:
        with hw_sim.serve({i: model for i in ids}, timing=True, baud=baud, return_delay_us=0) as bus:
            r = _time_family(bus.port, baud, model, ids, read, iterations, bus=bus)
        wire_ms = r["bytes"] * 10 / baud * 1e3
        rate, ceiling = 1e3 / r["median_ms"], 1e3 / wire_ms
        row = {"case": f"{read} {FAMILY_SERVOS} {model}", "read": read, "model": model,
               "servos": FAMILY_SERVOS, "baud": baud, "bytes": r["bytes"],
               "wire_ms": wire_ms, "ceiling_per_s": ceiling, "median_ms": r["median_ms"],
               "p99_ms": r["p99_ms"], "reads_per_s": rate, "ratio": rate / ceiling,
               "target": TARGET_RATIO if read == "fast" else None,
               "failures": r["failures"], "load_1min": os.getloadavg()[0]}
        if read == "fast":  # the pty's own ceiling for the same bytes, measured right after
            p = _pty_round_trips(r["host_bytes"], r["bytes"] - r["host_bytes"], baud, iterations)
            row.update({"host_bytes": r["host_bytes"], "pty_median_ms": p["median_ms"],
                        "pty_p99_ms": p["p99_ms"], "pty_ceiling_per_s": 1e3 / p["median_ms"],
                        "pty_ratio": 1e3 / p["median_ms"] / ceiling, "ratio_to_pty": p["median_ms"] / r["median_ms"]})
        rows.append(row)
    # A silent servo: servo 16 is asked for but absent, so the Fast Sync Read waits out the
    # SDK's deadline, tx time + 2 x latency timer + 2 ms, for the latency timer puppet set
    # (set_latency_assumption, as BusLink does from the adapter's timer). Cost: the median
    # reading with it minus the one without, in the same run on the same bus.
    with hw_sim.serve({i: X_MODEL for i in ids}, timing=True, return_delay_us=0) as bus:
        for latency in SILENT_LATENCIES_MS:
            count = max(10, iterations // (10 if latency > 1 else 3))
            clean = _time_sdk_fast(bus.port, ids, latency, count)
            silent = _time_sdk_fast(bus.port, ids + [FAMILY_SERVOS + 1], latency, count)
            rows.append({"case": f"silent servo, latency timer {latency} ms", "read": "fast",
                         "model": X_MODEL, "servos": FAMILY_SERVOS + 1, "baud": 1_000_000,
                         "latency_ms": latency, "clean_ms": clean, "median_ms": silent,
                         "silent_cost_ms": silent - clean, "sdk_deadline_ms": 2.0 * latency + 2.0,
                         "target": TARGET_SILENT_MS if latency == 1 else None})
    return rows


def _family_report(rows: list[dict]) -> None:
    print(f"{'case':<38} {'baud':>9} {'bytes':>5} {'wire_ms':>7} {'ceiling/s':>9} {'reads/s':>8} "
          f"{'ratio':>6} {'target':>6} {'fail':>4}")
    for r in rows:
        if "silent_cost_ms" in r:
            continue
        target = f">={r['target']:.1f}" if r["target"] else "-"
        print(f"{r['case']:<38} {r['baud']:>9} {r['bytes']:>5} {r['wire_ms']:>7.3f} "
              f"{r['ceiling_per_s']:>9.0f} {r['reads_per_s']:>8.0f} {r['ratio']:>6.2f} {target:>6} "
              f"{r['failures']:>4}")
    print("the pty's own ceiling (raw bytes of the same sizes, same timing, no protocol), and where a "
          "Fast Sync Read's time goes, ms:")
    print(f"{'case':<38} {'baud':>9} {'wire':>7} {'pty':>7} {'puppet':>7} {'pty-wire':>8} {'protocol':>8} "
          f"{'pty/wire':>8} {'puppet/pty':>10} {'load':>5}")
    for r in rows:
        if "pty_median_ms" in r:
            print(f"{r['case']:<38} {r['baud']:>9} {r['wire_ms']:>7.3f} {r['pty_median_ms']:>7.3f} "
                  f"{r['median_ms']:>7.3f} {r['pty_median_ms'] - r['wire_ms']:>8.3f} "
                  f"{r['median_ms'] - r['pty_median_ms']:>8.3f} {r['pty_ratio']:>8.2f} {r['ratio_to_pty']:>10.2f} "
                  f"{r['load_1min']:>5.1f}")
    print(f"{'case':<38} {'clean_ms':>8} {'silent_ms':>9} {'cost_ms':>8} {'2L+2_ms':>7} {'target':>7}")
    for r in rows:
        if "silent_cost_ms" in r:
            target = f"<={r['target']:.0f}" if r["target"] else "-"
            print(f"{r['case']:<38} {r['clean_ms']:>8.2f} {r['median_ms']:>9.2f} "
                  f"{r['silent_cost_ms']:>8.2f} {r['sdk_deadline_ms']:>7.1f} {target:>7}")


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
            rows: list[dict] | None = None, families: list[dict] | None = None) -> None:
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
        out = {"cases": [{k: c[k] for k in keys} for c in cases], "baseline": baseline,
               "families": families or []}
        Path(json_path).write_text(json.dumps(out, indent=2) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", default=None, help="write results to this JSON file")
    parser.add_argument("--iterations", type=int, default=300, help="reads per case")
    parser.add_argument("--no-reader", action="store_true",
                        help="skip bench/bus_reader.py's cases even if it exists")
    parser.add_argument("--families-only", action="store_true",
                        help="only the bus-at-its-limit table (15 servos, 1-4 Mbps, silent servo, P1)")
    args = parser.parse_args(argv)
    families = family_cases(args.iterations)
    _family_report(families)
    if args.families_only:
        if args.json:
            Path(args.json).write_text(json.dumps({"families": families}, indent=2) + "\n")
        return 0
    cases, baseline = run_cases(args.iterations)
    _report(cases, baseline, args.json, families=families)  # ours first: a failing reader bench loses nothing
    reader = [] if args.no_reader else _reader_cases()
    if reader:
        print("bus_reader cases (bench/bus_reader.py):")
        _report(cases + reader, baseline, args.json, rows=reader, families=families)
    return 0


if __name__ == "__main__":
    sys.exit(main())
