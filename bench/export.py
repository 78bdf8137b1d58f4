"""Export benchmark: milliseconds per exported frame for PC2, BVH, glTF and USD.

A synthetic take of the built-in critter (every servo moving, readings at about 200 Hz with
jittered times, 60 s by default) is exported at 30 fps to each format on its own, with
``puppet.export.export_take`` (resampling, solve, deformation, joint transforms, writing,
atomic rename: everything a user waits for). The baseline, measured in the same run, is the
shared part alone: resample + FAST solve + deformation (V' = M T) + joint transforms, writing
nothing (measured before and after the formats; the quieter run counts); each format's ratio
to it says what writing that format costs on top (BVH skips the deformation, so it can be < 1).

    python bench/export.py --json export.json [--seconds 60] [--fps 30]

JSON: {"cases": [{"format", "frames", "ms_per_frame", "bytes", "ratio_to_baseline"}],
       "baseline": {...}, "lbs_rms_pct", "lbs_max_pct", "take_seconds", "fps"}.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the puppet command does

import numpy as np  # noqa: E402

from puppet.bus import Reading  # noqa: E402
from puppet.export import JointTransforms, Outputs, Resampler, export_take  # noqa: E402
from puppet.loop import Pipeline  # noqa: E402
from puppet.rig import builtin  # noqa: E402
from puppet.take import TakeReader, TakeWriter  # noqa: E402

FORMATS = (("pc2", "mesh.pc2"), ("bvh", "skeleton.bvh"), ("gltf", "anim.glb"), ("usd", "anim.usdc"))


def make_take(path: Path, rig, seconds: float, rate_hz: float = 200.0) -> Path:
    """A take of ``rig``: smooth motion of every servo, readings jittered around rate_hz."""
    k = len(rig.servo_map)
    rng = np.random.default_rng(0)
    count = int(seconds * rate_hz) + 1
    times = np.round(np.arange(count) * 1e9 / rate_hz).astype(np.int64)
    times[1:-1] += rng.integers(-1_500_000, 1_500_000, count - 2)
    phase = rng.uniform(0, 2 * np.pi, k)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name, overwrite=True) as w:
        for t in times:
            s = t * 1e-9
            ticks = rig.servo_map.zero + 350 * np.sin(1.3 * s + phase) + 120 * np.sin(3.1 * s + 2 * phase)
            w.write(Reading(int(t), rig.servo_map.ids, ticks.astype(np.int32), np.ones(k, bool)))
    return path


def baseline(rig, take: Path, fps: float) -> dict:
    """The per-frame work every format shares, writing nothing."""
    start = time.perf_counter()
    ids = rig.servo_map.ids
    frames = Resampler(*TakeReader(take).arrays(ids=ids), ids, fps)
    with Pipeline(rig, render=False) as pipeline:
        M = pipeline.model.lbs_matrix()
        T = np.empty(pipeline.T.shape)
        deformed = np.empty((len(rig.V), 3))
        joints = JointTransforms(rig.skeleton.heads)
        for reading in frames:
            pipeline.solve(reading)
            T[...] = pipeline.T
            np.matmul(M, T, out=deformed)
            joints.update(pipeline.T)
    seconds = time.perf_counter() - start
    return {"what": "resample + solve + deform + joint transforms", "frames": len(frames),
            "ms_per_frame": 1e3 * seconds / len(frames)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="take length")
    parser.add_argument("--fps", type=float, default=30.0, help="export frame rate")
    parser.add_argument("--json", default=None, help="write the results here")
    args = parser.parse_args()

    rig = builtin()
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        take = make_take(folder / "take.mcap", rig, args.seconds)
        with Pipeline(rig, render=False):
            pass  # warm the precompute cache so no case pays for it
        first = baseline(rig, take, args.fps)
        cases, lbs = [], {}
        for fmt, name in FORMATS:
            target = folder / name
            report = export_take(rig, TakeReader(take), Outputs(**{fmt: target}), fps=args.fps)
            ms = 1e3 * report.seconds / report.frames
            cases.append({"format": fmt, "frames": report.frames, "ms_per_frame": round(ms, 3),
                          "bytes": target.stat().st_size})
            if fmt == "gltf":
                lbs = {"lbs_rms_pct": round(report.lbs_rms_pct, 4),
                       "lbs_max_pct": round(report.lbs_max_pct, 4)}
            target.unlink()
        last = baseline(rig, take, args.fps)  # before and after the formats: the quieter one
    base = min(first, last, key=lambda b: b["ms_per_frame"])
    for c in cases:
        c["ratio_to_baseline"] = round(c["ms_per_frame"] / base["ms_per_frame"], 3)
    base["ms_per_frame"] = round(base["ms_per_frame"], 3)
    result = {"cases": cases, "baseline": base, **lbs, "take_seconds": args.seconds,
              "fps": args.fps, "vertices": len(rig.V), "joints": rig.skeleton.bone_count,
              "note": "shared 2-core machine: compare ratios, not absolute times"}
    print(f"export of a {args.seconds:g} s take of the built-in critter ({len(rig.V)} vertices, "
          f"{rig.skeleton.bone_count} joints) at {args.fps:g} fps")
    print(f"{'format':8s} {'frames':>7s} {'ms/frame':>9s} {'x baseline':>11s} {'bytes':>12s}")
    print(f"{'baseline':8s} {base['frames']:7d} {base['ms_per_frame']:9.3f} {1.0:11.2f} {'-':>12s}")
    for c in cases:
        print(f"{c['format']:8s} {c['frames']:7d} {c['ms_per_frame']:9.3f} "
              f"{c['ratio_to_baseline']:11.2f} {c['bytes']:12d}")
    if lbs:
        print(f"glTF skeleton (LBS, the file's weights) vs FAST mesh: RMS {lbs['lbs_rms_pct']:.3f} %, "
              f"max {lbs['lbs_max_pct']:.3f} % of the bounding-box diagonal")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
