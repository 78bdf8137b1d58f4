"""A take replays and exports without the servo stack: with ``dynamixel_sdk``, ``serial`` and
``termios`` blocked from import (as on Windows, where termios does not exist), the replay, export
and view packages import, and ``puppet play`` and ``puppet export`` run to the end."""

import json
import subprocess
import sys

import numpy as np

from puppet.reading import Reading
from puppet.take import TakeWriter

BLOCKED = ("dynamixel_sdk", "serial", "termios")

# Installed first in every child interpreter. click's progress bar imports termios on POSIX
# (msvcrt on Windows): it is loaded before the block, then dropped from sys.modules, so any
# later `import termios` (from puppet code) meets the block.
BLOCKER = f"""
import importlib.abc, sys
import click._termui_impl
BLOCKED = {BLOCKED!r}
class Blocker(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{{name}} is blocked in this test")
sys.meta_path.insert(0, Blocker())
for name in [m for m in sys.modules if m.split(".")[0] in BLOCKED]:
    del sys.modules[name]
"""

IMPORTS = BLOCKER + """
import json
try:
    import puppet.bus
except ImportError as exc:
    bus = str(exc)
else:
    bus = "imported"
for name in [m for m in sys.modules if m.startswith("puppet.bus")]:
    del sys.modules[name]
import puppet.replay, puppet.export, puppet.view, puppet.take, puppet.rig, puppet.events
import puppet.cli
print(json.dumps({"bus": bus, "modules": sorted(sys.modules)}))
"""

RUN_CLI = BLOCKER + """
sys.argv = ["puppet"] + sys.argv[1:]
from puppet.cli import main
main()
"""


def _child(code: str, *args, cwd=None):
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=600, cwd=cwd)


def test_replay_export_and_view_import_without_the_servo_stack():
    out = _child(IMPORTS)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    # the block is real: the bus package needs the servo stack
    assert result["bus"] == "dynamixel_sdk is blocked in this test"
    loaded = [m for m in result["modules"] if m.split(".")[0] in BLOCKED or m.startswith("puppet.bus")]
    assert loaded == []
    assert {"puppet.replay", "puppet.export", "puppet.view", "puppet.cli.play", "puppet.cli.export",
            "puppet.reading", "puppet.events"} <= set(result["modules"])


def _critter_take(path, readings=12):
    """A take of the built-in critter at 30 readings per second, every servo moving."""
    from puppet.rig import builtin

    rig = builtin()
    ids, k = rig.servo_map.ids, len(rig.servo_map)
    with TakeWriter(path, ids=[int(i) for i in ids], models=dict(rig.servo_map.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
        for i in range(readings):
            ticks = (rig.servo_map.zero + 300 * np.sin(0.2 * i + np.arange(k))).astype(np.int32)
            writer.write(Reading(1_000_000_000 + round(i * 1e9 / 30), ids, ticks, np.ones(k, bool)))
    return path


def test_play_and_export_run_without_the_servo_stack(tmp_path):
    take = _critter_take(tmp_path / "take.mcap")  # recorded here, played in the blocked child
    play = _child(RUN_CLI, "play", str(take), "--out", "x.mp4", cwd=tmp_path)
    assert (play.returncode, play.stderr.count("Error")) == (0, 0), play.stderr
    export = _child(RUN_CLI, "export", str(take), "--gltf", "x.glb", "--pc2", "x.pc2", cwd=tmp_path)
    assert (export.returncode, export.stderr.count("Error")) == (0, 0), export.stderr
    for name in ("x.mp4", "x.glb", "x.pc2"):
        assert (tmp_path / name).stat().st_size > 1000


def test_the_link_and_the_view_share_the_net_module_not_each_other():
    """The Blender link's server reaches the live view's address, token and flood rules through
    ``puppet.net``, never the view's own modules (and the view never the link's)."""
    code = ("import json, sys\nimport puppet.link\nlink = sorted(sys.modules)\n"
            "for m in [m for m in sys.modules if m.startswith('puppet.')]:\n    del sys.modules[m]\n"
            "import puppet.view\nprint(json.dumps({'link': link, 'view': sorted(sys.modules)}))\n")
    out = _child(code)
    assert out.returncode == 0, out.stderr
    loaded = json.loads(out.stdout)
    assert "puppet.net.address" in loaded["link"] and "puppet.net.address" in loaded["view"]
    assert [m for m in loaded["link"] if m.startswith("puppet.view")] == []
    assert [m for m in loaded["view"] if m.startswith("puppet.link")] == []
