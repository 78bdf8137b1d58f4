"""Failures inside a batch: a corrupt or foreign take is reported and the others finish; a worker
killed mid-take is retried and every output ends complete (--resume: test_batch_resume.py)."""

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np

from puppet.bus import Reading
from puppet.take import TakeWriter


def batch_command(*args):
    return ["puppet", "batch", *map(str, args), "--json"]


def report_of(result):
    return json.loads(result.stdout.splitlines()[0])


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*") if p.name.startswith(".") or "partial" in p.name)


def test_a_corrupt_and_a_foreign_take_are_reported_and_the_others_finish(tmp_path, session,
                                                                        serial_outputs):
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    foreign = tmp_path / "foreign.mcap"
    with TakeWriter(foreign, ids=[1, 2], models={1: "XL330-M288", 2: "XL330-M288"},
                    rig_map_text="", calibration_text="", rig_name="other") as writer:
        writer.write(Reading(0, np.array([1, 2]), np.array([2048, 2048], np.int32),
                             np.ones(2, bool)))
    out = tmp_path / "out"
    result = subprocess.run(batch_command(session[0], corrupt, foreign, session[1], "--out", out,
                                          "--formats", "pc2", "--workers", 2),
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 3  # some takes failed (EXIT_FAILED)
    assert "Error: 2 of 4 takes failed" in result.stderr
    assert "Traceback" not in result.stderr
    rows = {Path(r["take"]).name: r for r in report_of(result)["takes"]}
    assert rows["corrupt.mcap"]["state"] == "failed"
    assert str(corrupt) in rows["corrupt.mcap"]["reason"]
    assert rows["foreign.mcap"]["state"] == "failed"
    assert ("the take stores no rig map (recorded with rig 'other' loaded from a character "
            "file); pass --rig") in rows["foreign.mcap"]["reason"]
    assert rows["foreign.mcap"]["outputs"] == []
    for take in session[:2]:
        assert rows[take.name]["state"] == "done"
        assert rows[take.name]["outputs"] == [str(out / f"{take.stem}.pc2")]
        assert (out / f"{take.stem}.pc2").read_bytes() == serial_outputs[take.stem]["pc2"]
    assert sorted(p.name for p in out.iterdir() if p.suffix == ".pc2") == ["take00.pc2",
                                                                          "take01.pc2"]
    assert sorted(p.name for p in out.iterdir() if p.suffix == ".json") == [
        "take00.batch.json", "take01.batch.json"]  # a failed take has no manifest
    assert "recorded with rig 'other'" in (out / "foreign.log").read_text()


def test_a_worker_killed_during_a_take_is_retried_and_every_output_is_complete(tmp_path, critter,
                                                                              tools):
    long_take = tools.write_take(tmp_path / "long.mcap", critter, readings=240, seed=7)
    short = [tools.write_take(tmp_path / f"short{i}.mcap", critter, seed=i) for i in range(2)]
    out = tmp_path / "out"
    formats = ("gltf", "pc2", "bvh")
    process = subprocess.Popen(batch_command(long_take, *short, "--out", out, "--formats",
                                             ",".join(formats), "--workers", 2),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    deadline = time.monotonic() + 300
    while killed is None and time.monotonic() < deadline and process.poll() is None:
        # a worker's staging folder <take>.<pid> holding a half-written file: mid-take
        for folder in out.glob(".puppet-batch.*.partial/long.*"):
            if any(".partial" in p.name for p in folder.iterdir()):
                killed = int(folder.suffix[1:])
                os.kill(killed, signal.SIGKILL)
                break
        time.sleep(0.01)
    stdout, stderr = process.communicate(timeout=600)
    assert killed is not None, "the long take never started"
    assert process.returncode == 0, stderr
    rows = {Path(r["take"]).name: r for r in json.loads(stdout.splitlines()[0])["takes"]}
    assert rows["long.mcap"]["retries"] == 1
    assert all(r["state"] == "done" for r in rows.values())
    expected = tools.serial(long_take, tmp_path / "serial", formats)
    suffix = {"gltf": ".glb", "pc2": ".pc2", "bvh": ".bvh"}
    for fmt in formats:
        assert (out / f"long{suffix[fmt]}").read_bytes() == expected[fmt]
        for take in short:
            assert (out / f"{take.stem}{suffix[fmt]}").stat().st_size > 0
    assert leftovers(out) == []
