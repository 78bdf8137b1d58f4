"""What a worker prints while it runs a take (Python prints and warnings, a native library
writing to file descriptor 2, Ray's coloured worker lines) is captured for that take's row and
log file, colour codes removed, and never reaches the terminal."""

import subprocess
import sys
import tempfile

SCRIPT = r"""
import os, sys, warnings
from pathlib import Path
from puppet.batch.row import TakeResult
from puppet.batch.task import captured_output

path = Path(sys.argv[1])
print("before", flush=True)
with captured_output(path):
    print("\x1b[31mprinted\x1b[0m")
    warnings.warn("a library's warning")
    os.write(2, b"\x1b[33m(raylet)\x1b[0m native line\n")
print("after", flush=True)
row = TakeResult(take="t.mcap")
for line in path.read_text().splitlines():
    row.add_log(line)
print(row.log_lines)
"""


def test_a_workers_output_is_captured_without_colour_and_not_shown(tmp_path):
    done = subprocess.run([sys.executable, "-P", "-c", SCRIPT, str(tmp_path / "output")],
                          capture_output=True, text=True, timeout=120, cwd=tempfile.gettempdir())
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    before, after, lines = done.stdout.splitlines()
    assert (before, after) == ("before", "after")
    assert "'printed'" in lines and "'(raylet) native line'" in lines
    assert "a library's warning" in lines and "\\x1b" not in lines
