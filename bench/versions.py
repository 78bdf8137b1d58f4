"""Before/after in one run: a benchmark of this checkout against the same benchmark of another
checkout (an earlier commit), run in turns, with after/before ratios of every figure both report.

    git worktree add --detach ../before <commit>           # then build it there (README, Developer loop)
    python bench/versions.py --before ../before --rounds 3 --json versions.json -- solver.py --quick
    python bench/versions.py --before ../before -- e2e.py --video --antialias fxaa --seconds 6 --rounds 1

Each round runs the benchmark script of each checkout (``<checkout>/bench/<script>``, with the
checkout's own ``.venv/bin/python`` when it has one, else this interpreter with the checkout first
on the path; refused when that interpreter imports ``puppet`` from elsewhere) with ``--json FILE`` added; numeric figures of the JSON files are flattened to
paths (``cases.0.us_per_iter``) and the median over rounds is compared for every path both
versions report. Turns (before, after, before, after, ...) put a shared machine's load on both.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def flatten(node, prefix: str = "") -> dict[str, float]:
    """{dotted path: number} of every int or float leaf of a JSON value (bools left out)."""
    out: dict[str, float] = {}
    if isinstance(node, dict):
        items = node.items()
    elif isinstance(node, list):
        items = enumerate(node)
    else:
        if isinstance(node, (int, float)) and not isinstance(node, bool):
            out[prefix] = float(node)
        return out
    for key, value in items:
        out.update(flatten(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def interpreter(checkout: Path) -> tuple[Path, dict]:
    """(python, environment) that run ``checkout``'s own code: its ``.venv/bin/python``, else
    this interpreter with the checkout first on the path. SystemExit when that interpreter
    imports ``puppet`` from elsewhere (an editable install's finder comes before the path:
    the run would measure the other version's code under this one's name)."""
    python = checkout / ".venv" / "bin" / "python"
    env = dict(os.environ)
    if not python.exists():
        python = Path(sys.executable)
        env["PYTHONPATH"] = os.pathsep.join([str(checkout), env.get("PYTHONPATH", "")])
    found = subprocess.run([str(python), "-c", "import puppet; print(puppet.__file__)"],
                           cwd=checkout, env=env, capture_output=True, text=True)
    where = Path(found.stdout.strip()).resolve() if found.returncode == 0 else None
    if where is None or checkout.resolve() not in where.parents:
        raise SystemExit(f"{checkout}: {python} imports puppet from "
                         f"{where or found.stderr.strip()[-200:]}, not from this checkout: "
                         f"build it there (python -m venv {checkout / '.venv'}, then pip install -e "
                         f"{checkout})")
    return python, env


def run_once(checkout: Path, script: str, args: list[str]) -> dict[str, float]:
    python, env = interpreter(checkout)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.json"
        subprocess.run([str(python), str(checkout / "bench" / script), *args, "--json", str(out)],
                       check=True, cwd=checkout, env=env, stdout=subprocess.DEVNULL)
        return flatten(json.loads(out.read_text()))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", required=True, type=Path, help="the other checkout (built)")
    ap.add_argument("--rounds", type=int, default=3, help="runs of each version, in turns")
    ap.add_argument("--json", help="write {path: {before, after, ratio}} here")
    ap.add_argument("--match", default="", help="only figures whose path contains this")
    ap.add_argument("bench", nargs=argparse.REMAINDER, help="-- SCRIPT [ARGS]: e.g. -- solver.py --quick")
    args = ap.parse_args(argv)
    bench = args.bench[1:] if args.bench[:1] == ["--"] else args.bench
    if not bench:
        ap.error("name the benchmark script after --")
    script, extra = bench[0], bench[1:]
    runs: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
    for r in range(args.rounds):
        for label, checkout in (("before", args.before.resolve()), ("after", HERE)):
            print(f"round {r + 1}/{args.rounds}: {label} ({checkout})", flush=True)
            runs[label].append(run_once(checkout, script, extra))
    table = {}
    shared = set.intersection(*(set(d) for d in runs["before"] + runs["after"]))
    for path in sorted(p for p in shared if args.match in p):
        before = statistics.median(d[path] for d in runs["before"])
        after = statistics.median(d[path] for d in runs["after"])
        table[path] = {"before": before, "after": after,
                       "ratio": after / before if before else float("nan")}
    width = max((len(p) for p in table), default=10)
    print(f"{'figure':<{width}}  {'before':>12}  {'after':>12}  {'after/before':>12}")
    for path, row in table.items():
        print(f"{path:<{width}}  {row['before']:>12.4g}  {row['after']:>12.4g}  {row['ratio']:>12.3f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"script": script, "args": extra, "rounds": args.rounds, "figures": table}, fh, indent=2)


if __name__ == "__main__":
    main()
