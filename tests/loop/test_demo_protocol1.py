"""The demo on the critter's Protocol 1.0 variant (critter_ax.toml: AX-12A and MX-28 on hw_sim):
the performance is played in each model's own ticks, read back through the real SDK as the
angles it swings, and ``puppet demo --ax`` runs end to end."""

from __future__ import annotations

import json
import math
import subprocess

import numpy as np

import hw_sim
from hw_sim.control_table import MODELS as SIM_MODELS, from_shaft
from puppet.bus import ServoReader
from puppet.demo import Performance
from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_AX_RIG


def test_the_performance_swings_each_servo_in_its_own_ticks():
    """hw_sim's motion speaks shaft counts; an AX-12A's Present Position, back in its own ticks,
    is zero + angle / radians_per_tick, as an X-series one is."""
    rig = load_rig(BUILTIN_AX_RIG)
    performance = Performance(rig)
    units = rig.servo_map.units
    for k, servo in enumerate(rig.servo_map.servos):
        _, amplitude, phase, _ = performance._params[servo.id]
        for t in (0.0, 0.3, 0.9, 1.7):
            angle = amplitude * math.sin(2 * math.pi * t / performance.period_s + phase)
            own = from_shaft(SIM_MODELS[servo.model].spec, performance.position(servo.id, t))
            assert abs(own - (units.zero[k] + angle / units.radians_per_tick[k])) < 1e-6


def test_the_ax_critter_read_back_stays_within_its_limits_and_out_of_the_dead_zone(wait_until):
    rig = load_rig(BUILTIN_AX_RIG)
    models = dict(rig.servo_map.models)
    with hw_sim.serve(models, motion=Performance(rig)) as bus:
        reader = ServoReader(bus.port, models)
        try:
            reader.open()
            rows = []

            def enough() -> bool:
                reading = reader.read()
                if reading.ok.all():
                    rows.append(rig.servo_map.angles(reading.ticks))
                return len(rows) >= 40
            wait_until(enough, what="40 clean readings of the AX critter")
            flagged = [i for i, h in reader.health.items() if h.dead_zone]
        finally:
            reader.close()
    angles = np.array(rows)
    lo, hi = np.array([s.limits for s in rig.servo_map.servos]).T
    # the performance's amplitude is 0.7 of the nearer limit: never at a limit, never clamped
    assert (angles > lo).all() and (angles < hi).all()
    assert (np.ptp(angles, axis=0) > 0.01).all()   # every servo, AX and MX, swung
    assert flagged == []


def test_demo_ax_runs_on_the_protocol1_variant(tmp_path):
    out = tmp_path / "ax.mp4"
    result = subprocess.run(["puppet", "demo", "--ax", "--seconds", "1", "--out", str(out), "--json",
                             "--size", "160", "120"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["read_mode"] == "bulk_read + read"   # MX-28 by Bulk Read, each AX-12A by a Read
    assert summary["frames"] >= 1
    assert out.stat().st_size > 0
    both = subprocess.run(["puppet", "demo", "--ax", "--dynamics", "--out", str(tmp_path / "x.mp4")],
                          capture_output=True, text=True, timeout=300)
    assert both.returncode == 1 and "Traceback" not in both.stderr
    assert both.stderr.strip().splitlines()[-1] == \
        "Error: --dynamics and --ax are two variants of the critter: choose one"
