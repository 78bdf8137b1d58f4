"""End-to-end benchmark: the live loop on the built-in character with hw_sim.

Servo reading (hw_sim, timing model on, 1 Mbps, fast sync read, 120 readings/s plus one asked
for by each frame) -> calibration -> FAST solve ->
render (this machine's GL renderer: Mesa llvmpipe on CPU machines) -> frame, with the bus read in
its own process. Two cases, run in turns (a shared machine's load falls on both alike):

    plain:       640x480, antialias 'auto' (FXAA on llvmpipe), no overlay, frames go to a sink
                 that only counts them (the loop without the video encoder);
    video-fxaa:  ``puppet demo`` as the README runs it: FXAA, the bone overlay, an MP4 written
                 (``--video --antialias fxaa`` selects this case alone).

    python bench/e2e.py --seconds 6 --rounds 2 --json e2e.json
    python bench/e2e.py --video --antialias fxaa --seconds 10
    python bench/e2e.py --compare --rounds 3      # each case also with the baseline settings

``--compare`` runs every case again with the settings before the issue-15 work (BASELINE:
FXAA in one pass over the whole frame, the character lit per pixel, the contact shadow at
128x128, every triangle drawn, the video encoder fed on the loop's thread with libx264's
default preset and this process's priority, the bus read at 250 Hz, no late latching and so no
reading requested ahead; the ground's backdrop has no switch), interleaved with the current
ones, and reports current / baseline ratios. (Dense skinning stays: the sparse "pairs" layout measured 2x slower
on llvmpipe, see puppet/render/renderer.py.) ``first_frame_s`` runs from this process's start (imports, then run_demo's
setup: rig, hw_sim, reader, pipeline) to the first frame, as ``puppet demo --json`` reports it.
``cpu_ms_per_frame``: CPU time per frame of the loop's thread (the critical path), of this
whole process (llvmpipe's rasterizer threads, the encoder thread) and of the child processes
(ffmpeg, the bus reader, hw_sim): figures a shared machine's load disturbs much less than fps.

JSON: {"cases": [{"case", "variant", "fps", "latency_median_ms", "latency_p99_ms",
"stages_ms": {stage: {"median", "p99", "mean"}}, "first_frame_s", "load_1min",
"cpu_ms_per_frame": {"loop_thread", "process", "children"}, ...}],
"ratios": [...]}. Targets: fps >= 60, median latency <= 16 ms, p99 <= 30 ms.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the puppet command does

from puppet.demo import DEMO_READ_RATE_HZ, run_demo  # noqa: E402
from puppet.loop import STAGES  # noqa: E402
from puppet.render import VideoSink  # noqa: E402
from puppet.render.sinks import DEFAULT_PRESET, ENCODER_NICE  # noqa: E402

#: Case name -> (video, antialias, overlay).
CASES = {"plain": (False, "auto", False), "video-fxaa": (True, "fxaa", True)}
#: Settings of run_demo / VideoSink before the issue-15 work, for --compare.
BASELINE = {"render": {"weight_layout": "dense", "fxaa_region": "frame", "fxaa_passes": "one_pass",
                       "shading": "pixel", "shadow_resolution": 128, "triangle_budget": None},
            "encoder": "inline", "preset": None, "latch_fps": None, "nice": 0, "rate_hz": 250.0}
CURRENT = {"render": {}, "encoder": "thread", "preset": DEFAULT_PRESET, "latch_fps": 60.0,
           "nice": ENCODER_NICE, "rate_hz": None}  # None: --rate


class CountingSink:
    """Takes frames and drops them (measures the loop, not the video encoder)."""

    def __init__(self):
        self.count = 0

    def write(self, image) -> None:
        self.count += 1

    def close(self) -> None:
        pass


def run_case(case: str, variant: str, args, folder: Path) -> dict:
    video, antialias, overlay = CASES[case]
    settings = BASELINE if variant == "baseline" else CURRENT
    info = {}

    def sinks_for(pipeline):
        info["gl"] = pipeline.renderer.gl_renderer
        info["antialias"] = pipeline.antialias
        info["skin"] = pipeline.renderer.weight_layout
        if video:
            return [VideoSink(folder / f"{case}-{variant}.mp4", args.fps, encoder=settings["encoder"],
                              preset=settings["preset"], nice=settings["nice"])]
        return [CountingSink()]

    loop_cpu = {}

    def on_frame(done: int) -> None:
        if done == 1:  # CPU of the loop's thread from the first frame on
            loop_cpu["start"] = time.thread_time()
        loop_cpu["end"] = time.thread_time()

    self_before = resource.getrusage(resource.RUSAGE_SELF)
    children_before = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary, report = run_demo(seconds=args.seconds, sinks_for=sinks_for, width=args.size[0],
                               height=args.size[1], iterations=args.iterations, overlay=overlay,
                               antialias=antialias, video_fps=args.fps, timing=True,
                               baud=1_000_000, rate_hz=settings["rate_hz"] or args.rate,
                               render_options=settings["render"],
                               on_frame=on_frame, latch_fps=settings["latch_fps"])
    d = summary.as_dict()
    frames = max(1, d["frames"])

    def cpu_ms(before, after) -> float:
        return round((after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime) * 1e3 / frames, 3)

    cpu = {"loop_thread": round((loop_cpu.get("end", 0) - loop_cpu.get("start", 0)) * 1e3 / frames, 3),
           "process": cpu_ms(self_before, resource.getrusage(resource.RUSAGE_SELF)),
           "children": cpu_ms(children_before, resource.getrusage(resource.RUSAGE_CHILDREN))}
    return {
        "case": case, "variant": variant, "video": video, "overlay": overlay,
        "frames": d["frames"], "fps": d["fps"],
        "latency_median_ms": d["latency_median_ms"], "latency_p99_ms": d["latency_p99_ms"],
        "stages_ms": d["stages_ms"], "first_frame_s": d["first_frame_s"], "cpu_ms_per_frame": cpu,
        "solver_us_per_iter": d["solver_us_per_iter"], "iterations_per_frame": d["iterations_per_frame"],
        "readings": d["readings"], "read_mode": report.read_mode, "bus_rate_hz": settings["rate_hz"] or args.rate,
        "renderer": info.get("gl", ""), "antialias": info.get("antialias", ""),
        "skinning": info.get("skin", ""), "encoder": settings["encoder"] if video else None,
        "size": list(args.size), "faults": d["faults"], "load_1min": round(os.getloadavg()[0], 2),
        "fps_vs_target_60": round(d["fps"] / 60.0, 3),
        "latency_vs_target_16ms": round(d["latency_median_ms"] / 16.0, 3),
    }


def _median(values):
    """The median of one column over the rounds (the mean of the middle two for an even count, each
    column on its own: two rounds give each column's midpoint, never the better fps paired with the
    worse latency of the other round); NaN entries (no figure) are left out."""
    values = [v for v in values if v == v]
    return statistics.median(values) if values else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each run")
    parser.add_argument("--rounds", type=int, default=1, help="runs of each case, in turns")
    parser.add_argument("--iterations", type=int, default=8, help="FAST iterations per frame")
    parser.add_argument("--size", type=int, nargs=2, default=(640, 480))
    parser.add_argument("--rate", type=float, default=DEMO_READ_RATE_HZ,
                        help="bus readings per second (the reader's steady rate; the baseline: 250)")
    parser.add_argument("--fps", type=float, default=30.0, help="video frame rate")
    parser.add_argument("--video", action="store_true", help="only the case that writes a video")
    parser.add_argument("--antialias", default=None, help="with --video: fxaa (the demo's case)")
    parser.add_argument("--compare", action="store_true", help="also run the baseline settings")
    parser.add_argument("--json", default=None, help="write the result here")
    args = parser.parse_args()
    cases = ["video-fxaa"] if args.video else list(CASES)
    if args.video and args.antialias not in (None, "fxaa"):
        parser.error("--video runs the demo's case: --antialias fxaa")
    variants = ["current", "baseline"] if args.compare else ["current"]

    results = []
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(args.rounds):
            for case in cases:
                for variant in variants:
                    results.append(run_case(case, variant, args, Path(folder)))
                    r = results[-1]
                    print(f"  {case:<10} {variant:<8} {r['fps']:7.2f} fps  latency {r['latency_median_ms']:6.2f} "
                          f"/ p99 {r['latency_p99_ms']:6.2f} ms  load {r['load_1min']}", flush=True)

    print(f"\ne2e live loop, built-in character, hw_sim timing on 1 Mbps, {args.size[0]}x{args.size[1]}, "
          f"renderer {results[0]['renderer']}; medians over {args.rounds} round(s)")
    header = (["case", "variant", "fps", "lat med", "lat p99", "first s", "cpu loop/proc/child"]
              + [f"{s} med/p99" for s in STAGES])
    rows = []
    summary = []
    for case in cases:
        for variant in variants:
            runs = [r for r in results if r["case"] == case and r["variant"] == variant]
            row = {"case": case, "variant": variant,
                   "fps": _median([r["fps"] for r in runs]),
                   "latency_median_ms": _median([r["latency_median_ms"] for r in runs]),
                   "latency_p99_ms": _median([r["latency_p99_ms"] for r in runs]),
                   "first_frame_s": _median([r["first_frame_s"] or float("nan") for r in runs]),
                   "cpu_ms_per_frame": {k: _median([r["cpu_ms_per_frame"][k] for r in runs])
                                        for k in ("loop_thread", "process", "children")},
                   "stages_ms": {s: {k: _median([r["stages_ms"][s][k] for r in runs]) for k in ("median", "p99")}
                                 for s in STAGES}}
            summary.append(row)
            rows.append([case, variant, f"{row['fps']:.1f}", f"{row['latency_median_ms']:.2f}",
                         f"{row['latency_p99_ms']:.2f}", f"{row['first_frame_s']:.2f}",
                         "/".join(f"{row['cpu_ms_per_frame'][k]:.1f}" for k in ("loop_thread", "process", "children"))]
                        + [f"{row['stages_ms'][s]['median']:.2f}/{row['stages_ms'][s]['p99']:.2f}" for s in STAGES])
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    for line in [header, *rows]:
        print("  " + "  ".join(str(x).ljust(w) for x, w in zip(line, widths)))
    ratios = []
    if args.compare:
        for case in cases:
            cur, base = (next(r for r in summary if r["case"] == case and r["variant"] == v)
                         for v in ("current", "baseline"))
            ratios.append({"case": case, "fps_ratio": round(cur["fps"] / base["fps"], 3),
                           "latency_median_ratio": round(cur["latency_median_ms"] / base["latency_median_ms"], 3),
                           "latency_p99_ratio": round(cur["latency_p99_ms"] / base["latency_p99_ms"], 3)})
            print(f"  {case}: current / baseline: fps x{ratios[-1]['fps_ratio']}, latency median "
                  f"x{ratios[-1]['latency_median_ratio']}, p99 x{ratios[-1]['latency_p99_ratio']}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"cases": results, "summary": summary, "ratios": ratios}, f, indent=2)


if __name__ == "__main__":
    main()
