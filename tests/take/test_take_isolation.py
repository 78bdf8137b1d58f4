"""Reading a take needs neither the servo bus (dynamixel_sdk) nor the native solver module."""

import json
import subprocess
import sys

SCRIPT = """
import json, sys
import puppet.take
r = puppet.take.TakeReader(sys.argv[1])
frames = list(puppet.take.Playback.of_take(r, r.metadata.ids, fps=60))
print(json.dumps({"readings": len(r), "frames": len(frames),
                  "modules": sorted(m for m in sys.modules if m.startswith(("puppet", "dynamixel")))}))
"""


def test_reading_a_take_loads_neither_the_bus_nor_native_code(take_path):
    out = subprocess.run([sys.executable, "-P", "-c", SCRIPT, str(take_path)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["readings"] == 200 and result["frames"] > 0
    modules = result["modules"]
    assert [m for m in modules if m.startswith("dynamixel_sdk")] == []
    assert "puppet._native" not in modules
    assert [m for m in modules if m.startswith(("puppet.bus", "puppet.fast", "puppet.rig"))] == []
    assert "puppet.reading" in modules
