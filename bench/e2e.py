"""End-to-end benchmark: the live loop on the built-in character with hw_sim.

Servo reading (hw_sim, timing model on, 1 Mbps, fast sync read) -> calibration -> FAST solve ->
render (640x480, this machine's GL renderer: Mesa llvmpipe on CPU machines; antialiasing 'auto':
none on a software renderer) -> frame, with the bus read in its own process. No video encoding:
frames go to a sink that only counts them.

    python bench/e2e.py --seconds 10 --json e2e.json

JSON: {"frames", "fps", "latency_median_ms", "latency_p99_ms", "solver_us_per_iter",
       "iterations_per_frame", ...}. Targets: fps >= 60, median latency <= 16 ms.
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the puppet command does

from puppet.demo import run_demo  # noqa: E402


class CountingSink:
    """Takes frames and drops them (measures the loop, not the video encoder)."""

    def __init__(self):
        self.count = 0

    def write(self, image) -> None:
        self.count += 1

    def close(self) -> None:
        pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--iterations", type=int, default=8, help="FAST iterations per frame")
    parser.add_argument("--size", type=int, nargs=2, default=(640, 480))
    parser.add_argument("--rate", type=float, default=250.0, help="bus readings per second")
    parser.add_argument("--json", default=None, help="write the result here")
    args = parser.parse_args()

    renderer_name = {}

    def sinks_for(pipeline):
        renderer_name["gl"] = pipeline.renderer.gl_renderer
        renderer_name["antialias"] = pipeline.antialias
        return [CountingSink()]

    summary, report = run_demo(seconds=args.seconds, sinks_for=sinks_for, width=args.size[0],
                               height=args.size[1], iterations=args.iterations, overlay=False,
                               timing=True, baud=1_000_000, rate_hz=args.rate)
    d = summary.as_dict()
    result = {
        "frames": d["frames"],
        "fps": d["fps"],
        "latency_median_ms": d["latency_median_ms"],
        "latency_p99_ms": d["latency_p99_ms"],
        "solver_us_per_iter": d["solver_us_per_iter"],
        "iterations_per_frame": d["iterations_per_frame"],
        "readings": d["readings"],
        "read_mode": report.read_mode,
        "bus_rate_hz": args.rate,
        "renderer": renderer_name.get("gl", ""),
        "antialias": renderer_name.get("antialias", ""),
        "size": list(args.size),
        "faults": d["faults"],
        "fps_vs_target_60": round(d["fps"] / 60.0, 3),
        "latency_vs_target_16ms": round(d["latency_median_ms"] / 16.0, 3),
    }
    rows = [("frames", result["frames"]), ("fps", result["fps"]),
            ("latency median ms", result["latency_median_ms"]),
            ("latency p99 ms", result["latency_p99_ms"]),
            ("solver us/iter", result["solver_us_per_iter"]),
            ("iterations/frame", result["iterations_per_frame"]),
            ("bus readings", result["readings"]), ("read mode", result["read_mode"]),
            ("renderer", result["renderer"]), ("antialias", result["antialias"]), ("faults", result["faults"] or "none")]
    width = max(len(k) for k, _ in rows)
    print(f"e2e live loop, built-in character, hw_sim timing on 1 Mbps, {args.size[0]}x{args.size[1]}")
    for key, value in rows:
        print(f"  {key:<{width}}  {value}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
