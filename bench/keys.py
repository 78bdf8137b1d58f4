"""Key-pose benchmark: FAST in-betweens against the per-vertex linear blend of the key meshes.

The built-in critter's example shot (``puppet.keys.example``: four held poses, ``--step``
frames apart at ``--fps``) is written as a shot and played through ``puppet.take.Playback``
(each in-between's joint rotations interpolated in rotation space, ``--interpolation``), every
frame solved by ``Pipeline.solve``. The baseline, in the same run, blends the two key meshes
vertex by vertex. For both: the mean ARAP energy of the in-betweens (the rig's energy type and
clusters, full space, ``puppet.keys.measure.arap_energy``) and the volume change of the closed
mesh, |V / V_rest − 1|, mean and max. FAST should be lower on both.

    python bench/keys.py --json keys.json [--step 12] [--fps 24] [--interpolation linear]

JSON: {"shot": {"keys", "step", "fps", "interpolation", "frames"}, "inbetweens",
       "fast": {"energy_mean", "volume_change_mean", "volume_change_max"}, "blend": {...},
       "energy_ratio": fast / blend, "volume_ratio": fast / blend (means), "free_bones_moving",
       "seconds"}.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the puppet command does

from puppet.keys import write_shot  # noqa: E402
from puppet.keys.example import critter_keys  # noqa: E402
from puppet.keys.measure import compare_inbetweens  # noqa: E402
from puppet.rig import builtin  # noqa: E402
from puppet.rig.calibration import Calibration  # noqa: E402
from puppet.take import Playback, TakeReader  # noqa: E402
from puppet.take.keys import INTERPOLATIONS  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=int, default=12, help="frames between keys")
    parser.add_argument("--fps", type=float, default=24.0, help="the shot's frame rate")
    parser.add_argument("--interpolation", choices=INTERPOLATIONS, default="linear")
    parser.add_argument("--json", default=None, help="write the results here")
    args = parser.parse_args()
    rig = builtin()
    keys = critter_keys(rig, step=args.step, fps=args.fps, interpolation=args.interpolation)
    header = {"ids": [int(i) for i in rig.servo_map.ids], "models": dict(rig.servo_map.models),
              "rig_map_text": "", "rig_name": rig.name,
              "calibration_text": Calibration.capture(rig.servo_map.ids,
                                                      rig.servo_map.zero).to_record()}
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as folder:
        shot = Path(folder) / "shot.mcap"
        write_shot(shot, header, keys)
        frames = Playback.of_take(TakeReader(shot), rig.servo_map.ids, fps=args.fps, rig=rig)
        report = compare_inbetweens(rig, frames, [k.frame - 1 for k in keys.keys])
    fast, blend = report["fast"], report["blend"]
    result = {"shot": {"keys": len(keys.keys), "step": args.step, "fps": args.fps,
                       "interpolation": args.interpolation, "frames": len(frames)},
              **report,
              "energy_ratio": fast["energy_mean"] / blend["energy_mean"],
              "volume_ratio": fast["volume_change_mean"] / blend["volume_change_mean"],
              "seconds": time.monotonic() - start}
    print(f"critter shot: {len(keys.keys)} keys, {args.step} frames apart at {args.fps:g} fps, "
          f"{args.interpolation}; {report['inbetweens']} in-betweens")
    print(f"{'':24}{'ARAP energy (mean)':>20}{'volume change mean':>20}{'max':>10}")
    for name, row in (("FAST (rotation space)", fast), ("per-vertex blend", blend)):
        print(f"{name:24}{row['energy_mean']:20.5g}{row['volume_change_mean'] * 100:19.3f}%"
              f"{row['volume_change_max'] * 100:9.3f}%")
    print(f"{'FAST / blend':24}{result['energy_ratio']:20.3f}{result['volume_ratio']:20.3f}")
    print(f"free bones moving in {report['free_bones_moving'] * 100:.0f}% of the in-betweens")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
