"""Blender for the tests: the ``bpy`` module (Blender as a Python module, from PyPI; the test
extras install it), run in a subprocess each time (it is heavy and keeps global state), and the
one skip reason where it cannot install. Load by path (pytest runs with --import-mode=importlib).
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys

BLENDER_TIMEOUT_S = 900  # one subprocess imports a few files; seconds on a quiet machine


def bpy_missing() -> str | None:
    """Why ``bpy`` cannot run here (a skip reason), or None."""
    if importlib.util.find_spec("bpy") is not None:
        return None
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    if version != "3.11":
        return (f"bpy (Blender 5.0 as a Python module) cannot install here: PyPI has its wheels "
                f"for Python 3.11 only and this is Python {version}; the test extras install it "
                f"under Python 3.11 (pip install '.[test]', as CI does)")
    return ("bpy (Blender 5.0 as a Python module) is not installed: pip install '.[test]' "
            "installs it (as CI does), or pip install bpy")


def run_bpy(*argv, cwd=None) -> str:
    """Run ``python ARGV...`` with bpy (a script path and its arguments, or ``-c CODE ...``);
    its stdout. AssertionError with the end of its output when it fails."""
    done = subprocess.run([sys.executable, *map(str, argv)], cwd=cwd, capture_output=True,
                          text=True, timeout=BLENDER_TIMEOUT_S)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout


def run_bpy_result(code: str, *args) -> dict:
    """Run ``code`` with bpy; the JSON it prints on one line after 'RESULT '."""
    out = run_bpy("-c", code, *args)
    return json.loads(next(x for x in out.splitlines() if x.startswith("RESULT "))[len("RESULT "):])
