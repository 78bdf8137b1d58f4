"""``bench/versions.py`` runs each checkout's own code: an interpreter that imports ``puppet``
from elsewhere (this checkout's editable install comes before any path) is refused, naming the
checkout, instead of measuring this version twice under two names."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _versions():
    spec = importlib.util.spec_from_file_location("bench_versions", ROOT / "bench" / "versions.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_checkout_whose_code_the_interpreter_would_not_import_is_refused(tmp_path):
    """A checkout with no .venv of its own whose ``puppet`` this interpreter would take from
    elsewhere (here: the checkout has none, so the installed one answers; with an editable
    install, any checkout's would be shadowed the same way)."""
    before = tmp_path / "before"
    (before / "bench").mkdir(parents=True)
    (before / "bench" / "where.py").write_text(  # what a run would report: a figure
        "import json, sys, puppet\njson.dump({'figure': 1}, open(sys.argv[-1], 'w'))\n")
    with pytest.raises(SystemExit) as refused:
        _versions().run_once(before, "where.py", [])
    assert str(before) in str(refused.value) and "not from this checkout" in str(refused.value)


def test_this_checkout_runs_its_own_code(tmp_path):
    python, _env = _versions().interpreter(ROOT)
    assert Path(python).exists()


@pytest.mark.parametrize("script, args", [
    ("e2e.py", ["--video", "--antialias", "fxaa", "--seconds", "1"]),
    ("view.py", ["--viewers", "0", "--seconds", "1", "--warmup", "0.5"])])
def test_the_live_benchmarks_run_and_report_their_figures(script, args, tmp_path):
    """The two benchmarks a change to the live loop is measured by (before/after through
    versions.py) run on this checkout and write their figures: a loop's callback that changed
    shape once left view.py failing at its first frame."""
    import subprocess
    import sys

    out = tmp_path / "bench.json"
    done = subprocess.run([sys.executable, str(ROOT / "bench" / script), *args, "--json", str(out)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    figures = _versions().flatten(json.loads(out.read_text()))
    fps = [v for k, v in figures.items() if k.rsplit(".", 1)[-1] in ("fps", "loop_fps")]
    assert fps and all(v > 0 for v in fps), figures
