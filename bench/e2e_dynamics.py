"""The demo loop (bench/e2e.py's plain case) on the built-in rig (critter.toml, no dynamics) and on
its secondary-motion variant (critter_dynamics.toml), in turns: fps, latency, the solve stage,
CPU per frame of the loop's thread, iterations per frame (a slower frame takes more 1/60 s steps).

    python bench/e2e_dynamics.py [ROUNDS]      # writes e2e_dynamics.json
"""

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import e2e  # noqa: E402

import puppet.demo as demo  # noqa: E402
from puppet.rig import builtin as shipped_builtin  # noqa: E402
from puppet.rig.load import BUILTIN_RIG, load_rig  # noqa: E402


def without_dynamics():
    return shipped_builtin()


def with_dynamics():
    return load_rig(BUILTIN_RIG.with_name("critter_dynamics.toml"))


def main():
    args = argparse.Namespace(seconds=8.0, iterations=8, size=(640, 480), rate=250.0, fps=30.0)
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    res = {"off": [], "on": []}
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(rounds):
            for variant, fn in (("off", without_dynamics), ("on", with_dynamics)):
                demo.builtin = fn
                r = e2e.run_case("plain", "current", args, Path(folder))
                res[variant].append(r)
                print(variant, f"{r['fps']:.1f} fps lat {r['latency_median_ms']:.2f}/{r['latency_p99_ms']:.2f} "
                      f"solve {r['stages_ms'].get('solve')} cpu {r['cpu_ms_per_frame']} it/frame {r['iterations_per_frame']} "
                      f"us/it {r['solver_us_per_iter']} load {r['load_1min']}", flush=True)
    with open("e2e_dynamics.json", "w") as fh:
        json.dump(res, fh, indent=1)


if __name__ == '__main__':
    main()
