"""Every take of a batch gets one row: state, worker, CPU and wall time, retries, output paths,
reason; in the summary table, in --json, in a log file per take in the output folder, and as one
progress line per finished take when stderr is not a terminal."""

import json
import re
import socket
import subprocess
from pathlib import Path

import numpy as np

from puppet.batch import BatchReport, TakeResult
from puppet.bus import Reading
from puppet.take import TakeWriter


def write_gap_take(path, rig):
    """A short take with a 2 s pause between two readings: playback cuts it and warns."""
    k = len(rig.servo_map)
    with TakeWriter(path, ids=[int(i) for i in rig.servo_map.ids],
                    models=dict(rig.servo_map.models), rig_map_text="", calibration_text="", rig_name=rig.name) as writer:
        for i, t in enumerate([0, 33_000_000, 2_033_000_000, 2_066_000_000]):
            ticks = (rig.servo_map.zero + 200 * np.sin(i + np.arange(k))).astype(np.int32)
            writer.write(Reading(t, rig.servo_map.ids, ticks, np.ones(k, bool)))
    return Path(path)


def test_rows_progress_lines_and_log_files(tmp_path, critter, tools):
    good = tools.write_take(tmp_path / "good.mcap", critter)
    gap = write_gap_take(tmp_path / "gap.mcap", critter)
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 4)
    out = tmp_path / "out"
    result = subprocess.run(["puppet", "batch", good, gap, corrupt, "--out", out, "--formats",
                             "pc2,bvh", "--workers", "1", "--json"],
                            capture_output=True, text=True, timeout=600)
    assert "Traceback" not in result.stderr
    report = json.loads(result.stdout)
    rows = {Path(r["take"]).name: r for r in report["takes"]}
    assert [r["state"] for r in rows.values()] == ["done", "done", "failed"]
    assert report["counts"] == {"done": 2, "skipped": 0, "failed": 1, "cancelled": 0,
                                "timed out": 0}
    for name in ("good", "gap"):
        row = rows[f"{name}.mcap"]
        assert row["outputs"] == [str(out / f"{name}.bvh"), str(out / f"{name}.pc2")]
        assert all(Path(p).stat().st_size > 0 for p in row["outputs"])
        host, pid = row["worker"].rsplit(":", 1)
        assert host == socket.gethostname() and int(pid) > 0
        assert row["cpu_s"] > 0 and row["wall_s"] > 0 and row["retries"] == 0
        assert row["log"] == str(out / f"{name}.log")
    assert rows["corrupt.mcap"]["outputs"] == [] and str(corrupt) in rows["corrupt.mcap"]["reason"]
    assert "gap(s) between readings" in rows["gap.mcap"]["warnings"][0]

    # progress: stderr is a pipe here, so one line per finished take, no progress bar
    progress = [line for line in result.stderr.splitlines() if line.startswith("[")]
    assert len(progress) == 3
    assert {re.match(r"\[(\d)/3\] (\S+) (\w+)", line).group(2, 3) for line in progress} == {
        (str(good), "done"), (str(gap), "done"), (str(corrupt), "failed")}
    assert f"warning: {gap}: 1 gap(s)" in result.stderr

    # one log file per take, with its row, warnings and errors
    gap_log = (out / "gap.log").read_text()
    assert "state: done" in gap_log and "warning: 1 gap(s)" in gap_log
    assert f"output: {out / 'gap.pc2'}" in gap_log
    corrupt_log = (out / "corrupt.log").read_text()
    assert "state: failed" in corrupt_log and f"error: {corrupt}" in corrupt_log
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["good.pc2", "good.bvh", "good.log", "good.batch.json", "gap.pc2", "gap.bvh", "gap.log",
         "gap.batch.json", "corrupt.log"])


def test_the_summary_table_shows_every_row(tmp_path):
    out = tmp_path / "out"
    done = TakeResult(take="a.mcap", worker="host:11", seconds=1.5, cpu_seconds=1.25, retries=1,
                      files={"pc2": str(out / "a.pc2"), "bvh": str(out / "a.bvh")})
    failed = TakeResult.failed("b.mcap", "b.mcap: the take holds no readings", worker="host:12")
    report = BatchReport(engine="local", workers=2, out=str(out), rows=[done, failed])
    lines = report.table().splitlines()
    assert lines[0].split() == ["take", "state", "worker", "cpu", "s", "wall", "s", "retries",
                                "outputs", "reason"]
    assert lines[1].split() == ["a.mcap", "done", "host:11", "1.25", "1.50", "1", "a.bvh",
                                "a.pc2"]
    assert lines[2].split()[:7] == ["b.mcap", "failed", "host:12", "0.00", "0.00", "0", "-"]
    assert lines[2].endswith("b.mcap: the take holds no readings")
    assert lines[3].startswith("1 done, 1 failed in ")
    assert str(out) in lines[3]


def test_engine_lines_are_kept_without_colour_and_bounded():
    from puppet.batch.row import MAX_LOG_LINES

    row = TakeResult(take="a.mcap")
    row.add_log("\x1b[36m(_ray_task pid=42)\x1b[0m solving a.mcap\n")
    assert row.log_lines == ["(_ray_task pid=42) solving a.mcap"]
    for i in range(MAX_LOG_LINES + 10):
        row.add_log(f"line {i}")
    assert len(row.log_lines) == MAX_LOG_LINES + 1
    assert row.log_lines[-1].startswith("(more lines dropped")
    assert "engine:\n  (_ray_task pid=42) solving a.mcap\n" in row.log_text()
