"""Live link benchmark: reading -> applied in Blender, bones only and with the exact mesh, against
the live view's reading -> page (the baseline) and a plain loopback client, in the same run.

A take of the built-in critter (``--seconds`` at ``--fps``, every servo moving) is played with
``puppet play TAKE --link 127.0.0.1:0 --fps FPS`` (frame k handed out at k / fps on the wall
clock: its "reading" time) three times, each to one client:

- plain:  a Python client of ``puppet.link.wire`` that acks each frame on receipt (the floor:
          puppet's own send path and loopback TCP);
- bones:  Blender (``bpy``, in a subprocess) with the add-on from ``puppet blender addon``
          installed, posing the critter's glTF import by calling the add-on's own tick in a loop
          (module mode has no event loop; in Blender a ``bpy.app.timers`` callback does it);
- mesh:   the same with "Exact mesh" on (the 24 910 FAST vertices written every frame).

The baseline, view: the live view's own measurement (``bench/view.py``'s ``run_case``, one
headless Chromium page through playwright on the demo loop): from the reading's time to the
page's acknowledgement of the frame that shows it, median and p99; its fps is the page's.

Latency is puppet's: from the frame's reading time to the client's ack arriving (so it holds
the return trip too), median and p99 over every acked frame; fps applied = frames acked /
the take's length.

    python bench/link.py --json link.json [--seconds 10] [--fps 60] [--no-view]

The Blender rows also give the Blender-side cost of one update, median CPU ms (the thread's CPU
time: a loaded machine does not inflate it): "receive" (reading the socket, decoding), "bones"
(the add-on posing the armature), "mesh" (the add-on writing the exact mesh on its copy) and
"evaluate" (``view_layer.update()`` after the tick: what Blender does before it draws the new
pose: with bones only, the Armature modifier deforming the user's mesh; with the exact mesh,
the copy's normals, the user's mesh hidden), their sum and the capacity 1000 / sum fps.
puppet runs as ``sys.executable -m puppet.cli``: no ``puppet`` on PATH needed.

JSON: {"fps", "seconds", "frames", "view" | "plain" | "bones" | "mesh": {"applied",
       "fps_applied", "median_ms", "p99_ms", "client": {"applied", "skipped", "costs_ms":
       {"receive", "bones", "mesh", "evaluate"}, "update_ms", "capacity_fps"} (Blender rows)},
       "machine": {"cpus", "load_1min"}}.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the puppet command does

import numpy as np  # noqa: E402

from puppet.link import wire  # noqa: E402
from puppet.reading import Reading  # noqa: E402
from puppet.rig import builtin  # noqa: E402
from puppet.take import TakeWriter  # noqa: E402

SUMMARY = re.compile(r"(\d+) applied; reading->applied median ([\d.]+) ms, p99 ([\d.]+) ms")
ROWS = ("view", "plain", "bones", "mesh")

BLENDER = """
import sys, time, json, bpy
zip_path, glb, port, mesh = sys.argv[-4], sys.argv[-3], int(sys.argv[-2]), sys.argv[-1] == "1"
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module="puppet_link")
import puppet_link
scene = bpy.context.scene
scene.render.fps = 60
bpy.ops.import_scene.gltf(filepath=glb)
s = scene.puppet_link
s.port = port
s.armature = next(o for o in scene.objects if o.type == "ARMATURE")
s.mesh = next(o for o in scene.objects if o.type == "MESH")
s.use_mesh = mesh
bpy.ops.puppet_link.connect()
link = puppet_link.LINK
evaluate = []
while link.state != "waiting":
    applied = link.frames_applied
    puppet_link.tick()
    if link.frames_applied > applied:  # what Blender does before it draws: evaluate the scene
        start = time.thread_time()
        bpy.context.view_layer.update()
        evaluate.append((time.thread_time() - start) * 1e3)
link.close()
costs = {name: list(values) for name, values in link.costs.items()}
costs["evaluate"] = evaluate
print("APPLIED", json.dumps({"applied": link.frames_applied, "skipped": link.skipped,
                             "costs": costs}))
"""
PUPPET = [sys.executable, "-m", "puppet.cli"]  # this Python's puppet: no venv bin on PATH needed
COSTS = ("receive", "bones", "mesh", "evaluate")


def write_take(path: Path, rig, seconds: float, fps: float) -> None:
    servos = rig.servo_map
    k = len(servos)
    with TakeWriter(path, ids=[int(i) for i in servos.ids], models=dict(servos.models),
                    rig_map_text="", calibration_text="", rig_name=rig.name,
                    overwrite=True) as w:
        for i in range(int(seconds * fps) + 1):
            ticks = (servos.zero + 380 * np.sin(2.0 * i / fps + np.arange(k))).astype(np.int32)
            w.write(Reading(5_000_000_000 + round(i * 1e9 / fps), servos.ids, ticks,
                            np.ones(k, bool)))


def view_baseline(seconds: float) -> dict:
    """The live view's reading -> page with one Chromium page (bench/view.py's own case)."""
    spec = importlib.util.spec_from_file_location("bench_view", Path(__file__).with_name("view.py"))
    view = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(view)
    case = view.run_case(1, seconds, 4.0, (640, 480))
    return {"applied": None, "fps_applied": case["page_fps"],
            "median_ms": case["latency_median_ms"], "p99_ms": case["latency_p99_ms"]}


def plain_client(port: int) -> None:
    """Read frames and ack each on receipt, until puppet says bye."""
    import socket

    sock = socket.create_connection(("127.0.0.1", port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.sendall(wire.encode_json(wire.CONNECT, {"protocol": wire.PROTOCOL, "mesh": False,
                                                 "name": "bench"}))
    reader = wire.Reader()
    while True:
        data = sock.recv(1 << 20)
        if not data:
            return
        reader.feed(data)
        for kind, body in reader.messages():
            if kind == wire.FRAME_KIND:
                sock.sendall(wire.encode_ack(wire.decode(kind, body).seq, time.monotonic()))
            elif kind == wire.BYE:
                return


PUPPET = [sys.executable, "-P", "-c", "from puppet.cli import main; main()"]
"""The puppet command, run by this interpreter: no need for the venv's bin on PATH."""


def play(take: Path, fps: float, client) -> dict:
    """Play the take to one client; puppet's summary figures."""
    proc = subprocess.Popen([*PUPPET, "play", str(take), "--link", "127.0.0.1:0", "--fps",
                             f"{fps:g}"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    port = None
    for line in proc.stderr:
        if line.startswith("link: listening on"):
            port = int(line.split()[3].rsplit(":", 1)[1])
            break
    if port is None:
        raise SystemExit(f"puppet play did not listen: {proc.stderr.read()}")
    drain = threading.Thread(target=proc.stderr.read, daemon=True)
    drain.start()
    client_out = client(port)
    out, _ = proc.communicate(timeout=900)
    found = SUMMARY.search(out)
    if not found:
        raise SystemExit(f"no link line in puppet's summary:\n{out}")
    return {"applied": int(found.group(1)), "median_ms": float(found.group(2)),
            "p99_ms": float(found.group(3)), "client": client_out}


def _median(values) -> float | None:
    return round(float(np.median(values)), 3) if len(values) else None


def _shown(value) -> str:
    return "-" if value is None else f"{value:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="length of the take")
    parser.add_argument("--fps", type=float, default=60.0, help="frames per second played")
    parser.add_argument("--json", default=None, help="write the results here")
    parser.add_argument("--no-view", action="store_true",
                        help="leave out the live view's row (bench/view.py's case, Chromium)")
    args = parser.parse_args()
    rig = builtin()
    result = {"fps": args.fps, "seconds": args.seconds,
              "view": None if args.no_view else view_baseline(args.seconds)}
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        take, glb, addon = folder / "take.mcap", folder / "critter.glb", folder / "puppet_link.zip"
        write_take(take, rig, args.seconds, args.fps)
        subprocess.run([*PUPPET, "export", str(take), "--gltf", str(glb), "--fps",
                        f"{args.fps:g}"], check=True, capture_output=True)
        subprocess.run([*PUPPET, "blender", "addon", "--out", str(addon)], check=True,
                       capture_output=True)
        result["frames"] = int(args.seconds * args.fps) + 1

        def blender(mesh: bool):
            def run(port: int):
                done = subprocess.run([sys.executable, "-c", BLENDER, str(addon), str(glb),
                                       str(port), str(int(mesh))], capture_output=True, text=True)
                line = next((x for x in done.stdout.splitlines() if x.startswith("APPLIED")), None)
                if line is None:
                    raise SystemExit(f"Blender failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
                out = json.loads(line[len("APPLIED "):])
                costs = {name: _median(out["costs"].get(name, [])) for name in COSTS}
                total = sum(v for v in costs.values() if v is not None)
                return {"applied": out["applied"], "skipped": out["skipped"], "costs_ms": costs,
                        "update_ms": round(total, 3),
                        "capacity_fps": round(1000.0 / total, 1) if total else None}
            return run

        for name, client in (("plain", plain_client), ("bones", blender(False)),
                             ("mesh", blender(True))):
            figures = play(take, args.fps, client)
            figures["fps_applied"] = round(figures["applied"] / args.seconds, 1)
            result[name] = figures
    result["machine"] = {"cpus": os.cpu_count(), "load_1min": round(os.getloadavg()[0], 2)}
    print(f"critter, {result['frames']} frames at {args.fps:g} fps, loopback "
          f"({result['machine']['cpus']} cpus, load {result['machine']['load_1min']})")
    print(f"{'client':<8}{'applied':>9}{'fps':>8}{'median ms':>11}{'p99 ms':>9}"
          + "".join(f"{c + ' ms':>12}" for c in COSTS) + f"{'update ms':>11}{'capacity':>10}")
    for name in ROWS:
        r = result[name]
        if r is None:
            continue
        costs = r.get("client", {}).get("costs_ms", {}) if isinstance(r.get("client"), dict) else {}
        client = r.get("client") if isinstance(r.get("client"), dict) else {}
        print(f"{name:<8}{str(r['applied'] or '-'):>9}{r['fps_applied']:>8}{r['median_ms']:>11}"
              f"{r['p99_ms']:>9}" + "".join(f"{_shown(costs.get(c)):>12}" for c in COSTS)
              + f"{_shown(client.get('update_ms')):>11}{_shown(client.get('capacity_fps')):>10}")
    print("Blender-side CPU ms per update, medians: receive (socket, decode), bones (posing the "
          "armature), mesh (the exact mesh's bulk write), evaluate (Blender's scene update after "
          "it, before a draw); update: their sum; capacity: 1000 / update, the rate Blender's "
          "side sustains on one core (applied fps also needs puppet's side and the machine)")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
