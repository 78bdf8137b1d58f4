"""Batch benchmark: takes per minute with 1 and 2 workers on each engine, overhead per task, the
rig precompute shared once against per take, and the per-take cost model of docs/scale.md.

Takes are synthetic takes of the built-in critter (every servo moving, 240 readings per second
as `puppet record` gets them: about 35 kB per second of take).
Each case runs ``puppet.batch.run_batch`` (the driver) over them; outputs go to a temporary
folder. The FAST precompute cache is pointed at an empty folder, so the rig precompute really
runs (once per batch: that is what is shared; "per take" is what recomputing it in every task
would cost). Ray is started before its cases (its start-up time is reported apart) and stopped
after them; without Ray installed its cases are left out and the table says so.

    python bench/batch.py --json batch.json                 # short: 4 takes of 2 s
    python bench/batch.py --json batch.json --full          # the issue's 8 takes of 10 s
    python bench/batch.py --takes 8 --seconds 10 --engines local --formats pc2,gltf

Figures: takes_per_min = takes / wall minutes of the batch (precompute included);
overhead_ms_per_task = (wall - precompute - sum of task seconds / workers) / takes: process
start, pickling, pipes or Ray scheduling and the driver's writes, per take. The ratio of 2 to 1
worker(s) is printed per engine and format set (on a 2-core machine it approaches 2 for
solve-heavy formats when nothing else runs; a shared machine lowers it).

JSON: {"cases": [{"engine", "workers", "takes", "formats", "takes_per_min",
"overhead_ms_per_task", "precompute_s", "precompute_per_take_s", "seconds", "task_seconds_sum",
"task_cpu_seconds_sum", "load_1min": [before, after] (the machine's 1-minute load average:
2 cores, so above 2 means other work competed), "cpu_share_per_worker": the takes' CPU seconds /
(wall seconds x workers): 1.0 when each worker had a core to itself}], "ratios": [...],
"cost": {per-take CPU seconds and bytes}, "ray_start_s", "shared_bytes", "precompute_bytes"}.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the puppet command does
# A cold cache: the one cache root (puppet.cache.ENV) in an empty folder, emptied before each
# case, so every rig precompute below really runs.
CACHE = Path(tempfile.mkdtemp(prefix="puppet-bench-cache-"))
os.environ["PUPPET_CACHE"] = str(CACHE)

import numpy as np  # noqa: E402

import puppet.cache  # noqa: E402
from puppet.batch import run_batch  # noqa: E402
from puppet.bus import Reading  # noqa: E402
from puppet.loop import Pipeline, RigPrecompute  # noqa: E402
from puppet.rig import builtin  # noqa: E402
from puppet.take import TakeWriter  # noqa: E402


TAKE_RATE_HZ = 240.0
"""Readings per second of the bench's takes: what `puppet record` gets from 15 servos on a
1 Mbit/s bus (about 145 bytes per reading: 35 kB per second of take)."""


def make_take(path: Path, rig, seconds: float, seed: int, rate_hz: float = TAKE_RATE_HZ) -> Path:
    """A take of ``rig``: smooth motion of every servo at rate_hz readings per second."""
    k = len(rig.servo_map)
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, k)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name, overwrite=True) as w:
        for i in range(int(seconds * rate_hz) + 1):
            s = i / rate_hz
            ticks = rig.servo_map.zero + 350 * np.sin(1.3 * s + phase) + 120 * np.sin(3.1 * s + 2 * phase)
            w.write(Reading(int(round(s * 1e9)), rig.servo_map.ids, ticks.astype(np.int32),
                            np.ones(k, bool)))
    return path


def empty_cache() -> None:
    """Remove everything cached (the FAST precompute and any other part's files)."""
    assert puppet.cache.cache_root() == CACHE, "the bench must not touch the user's cache"
    shutil.rmtree(CACHE, ignore_errors=True)
    CACHE.mkdir()


def cpu_now() -> tuple[float, float]:
    """(this process's CPU seconds, reaped children's CPU seconds: ffmpeg)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time(), children.ru_utime + children.ru_stime


def cost_model(rig, take: Path, folder: Path, fps: float, size: tuple[int, int]) -> dict:
    """Per-take CPU seconds of solve, render and encode, and the bytes a take moves."""
    from puppet.export import Outputs, export_take
    from puppet.render import VideoSink
    from puppet.replay import open_take
    from puppet.take import Playback, TakeReader

    precompute = RigPrecompute.for_rig(rig)
    replay_rig, reader = open_take(take, rig)
    ids = replay_rig.servo_map.ids
    frames = list(Playback.of_take(TakeReader(take), ids, fps=fps))
    with Pipeline(replay_rig, render=True, width=size[0], height=size[1], antialias="msaa",
                  overlay=True, precompute=precompute) as pipeline:
        c0 = cpu_now()[0]
        for reading in frames:
            pipeline.solve(reading)
        solve = cpu_now()[0] - c0
        images = []
        c0 = cpu_now()[0]
        for reading in frames:
            pipeline.solve(reading)
            images.append(pipeline.draw())
        render = cpu_now()[0] - c0 - solve
    sink = VideoSink(folder / "cost.mp4", fps)
    c0 = cpu_now()
    for image in images:
        sink.write(image)
    sink.close()
    c1 = cpu_now()
    encode = (c1[0] - c0[0]) + (c1[1] - c0[1])
    c0 = cpu_now()[0]
    export_take(replay_rig, reader, Outputs(pc2=folder / "cost.pc2", gltf=folder / "cost.glb"),
                fps=fps, precompute=precompute)
    export = cpu_now()[0] - c0
    return {"frames": len(frames), "solve_cpu_s": round(solve, 4), "render_cpu_s": round(render, 4),
            "encode_cpu_s": round(encode, 4), "export_pc2_gltf_cpu_s": round(export, 4),
            "take_bytes": take.stat().st_size,
            "mp4_bytes": (folder / "cost.mp4").stat().st_size,
            "pc2_bytes": (folder / "cost.pc2").stat().st_size,
            "gltf_bytes": (folder / "cost.glb").stat().st_size}


def run_case(engine: str, workers: int, takes: list[Path], out: Path, rig, formats: str,
             fps: float, size, precompute_cold_s: float) -> dict:
    load_before = os.getloadavg()[0]
    report = run_batch([str(t) for t in takes], out, rig=rig, formats=formats,
                       fps=fps, size=size, engine=engine, workers=workers)
    if report.failed:  # the failed take's whole row and log: the worker's own error
        sys.exit(f"bench: {engine} case failed: {report.failed[0].take}: {report.failed[0].error}"
                 f"\n{report.failed[0].log_text()}")
    busy = sum(r.seconds for r in report.rows) / workers
    overhead = max(0.0, report.seconds - report.precompute_s - busy) / len(takes)
    return {"engine": engine, "workers": workers, "takes": len(takes), "formats": formats,
            "takes_per_min": round(len(takes) / (report.seconds / 60), 3),
            "overhead_ms_per_task": round(overhead * 1e3, 1),
            "precompute_s": round(report.precompute_s, 4),
            "precompute_per_take_s": round(precompute_cold_s * len(takes), 4),
            "seconds": round(report.seconds, 3), "shared_bytes": report.shared_bytes,
            "task_seconds_sum": round(sum(r.seconds for r in report.rows), 3),
            "task_cpu_seconds_sum": round(sum(r.cpu_seconds for r in report.rows), 3),
            "precompute_bytes": report.precompute_bytes,
            "load_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)],
            "cpu_share_per_worker": round(sum(r.cpu_seconds for r in report.rows)
                                          / (report.seconds * workers), 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None, help="write the results here")
    parser.add_argument("--takes", type=int, default=4, help="takes per case (default 4)")
    parser.add_argument("--seconds", type=float, default=2.0, help="seconds per take (default 2)")
    parser.add_argument("--full", action="store_true", help="the issue's cases: 8 takes of 10 s")
    parser.add_argument("--engines", default="local,ray", help="comma-separated: local, ray")
    parser.add_argument("--formats", action="append", default=None,
                        help="a format set per case, e.g. pc2,gltf (repeatable; default: "
                             "pc2,gltf,bvh and mp4)")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"))
    args = parser.parse_args()
    if args.full:
        args.takes, args.seconds = 8, 10.0
    format_sets = args.formats or ["pc2,gltf,bvh", "mp4"]
    engines = [e.strip() for e in args.engines.split(",") if e.strip()]
    rig = builtin()
    folder = Path(tempfile.mkdtemp(prefix="puppet-bench-batch-"))
    takes = [make_take(folder / f"take{i:02d}.mcap", rig, args.seconds, seed=i)
             for i in range(args.takes)]

    empty_cache()
    start = time.perf_counter()
    cold = RigPrecompute.for_rig(rig)  # the cache is empty: the full precompute
    precompute_cold_s = time.perf_counter() - start
    empty_cache()  # every batch below computes it again, once
    result = {"cases": [], "ratios": [], "takes": args.takes, "seconds_per_take": args.seconds,
              "precompute_cold_s": round(precompute_cold_s, 4),
              "precompute_bytes": cold.nbytes(), "ray_start_s": None,
              "cost": cost_model(rig, takes[0], folder, args.fps, tuple(args.size))}

    for engine in engines:
        if engine == "ray":
            try:
                import ray
            except ImportError:
                print("ray: not installed (pip install 'puppet[ray]'): its cases are left out")
                continue
        for formats in format_sets:
            for workers in (1, 2):
                if engine == "ray":
                    t0 = time.perf_counter()
                    # a private instance, as puppet batch starts (never a running cluster)
                    os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # as the engine's
                    ray.init(address="local", num_cpus=workers, include_dashboard=False,
                             log_to_driver=False, logging_level="ERROR")
                    result["ray_start_s"] = round(time.perf_counter() - t0, 3)
                try:
                    empty_cache()
                    out = folder / f"out-{engine}-{workers}-{formats.replace(',', '-')}"
                    case = run_case(engine, workers, takes, out, rig, formats, args.fps,
                                    tuple(args.size), precompute_cold_s)
                finally:
                    if engine == "ray":
                        ray.shutdown()
                result["cases"].append(case)
                print(f"  {engine} {workers} worker(s) {formats}: {case['takes_per_min']} takes/min",
                      flush=True)
            one, two = result["cases"][-2:]
            result["ratios"].append({"engine": engine, "formats": formats,
                                     "two_over_one": round(two["takes_per_min"] / one["takes_per_min"], 3)})

    print(f"\n{args.takes} takes of {args.seconds:g} s, critter, {args.fps:g} fps "
          f"(shared machine: ratios, not absolute figures)")
    print(f"{'engine':6} {'workers':>7} {'formats':10} {'takes/min':>9} {'overhead ms/task':>16} "
          f"{'precompute s':>12} {'per take s':>10}")
    for c in result["cases"]:
        print(f"{c['engine']:6} {c['workers']:>7} {c['formats']:10} {c['takes_per_min']:>9.2f} "
              f"{c['overhead_ms_per_task']:>16.1f} {c['precompute_s']:>12.3f} "
              f"{c['precompute_per_take_s']:>10.3f}  load {c['load_1min'][0]:.1f}-"
              f"{c['load_1min'][1]:.1f}, each worker had {c['cpu_share_per_worker']:.2f} core")
    for r in result["ratios"]:
        print(f"2 workers / 1 worker, {r['engine']} {r['formats']}: {r['two_over_one']:.2f}")
    cost = result["cost"]
    print(f"per take ({cost['frames']} frames) CPU s: solve {cost['solve_cpu_s']}, render "
          f"{cost['render_cpu_s']}, encode {cost['encode_cpu_s']}, export pc2+gltf "
          f"{cost['export_pc2_gltf_cpu_s']}; bytes: take {cost['take_bytes']}, mp4 "
          f"{cost['mp4_bytes']}, pc2 {cost['pc2_bytes']}, glb {cost['gltf_bytes']}; shared once "
          f"per worker: precompute {result['precompute_bytes']} bytes")
    if result["ray_start_s"] is not None:
        print(f"ray start (apart from the cases): {result['ray_start_s']} s")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
