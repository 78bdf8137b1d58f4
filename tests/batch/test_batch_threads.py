"""The same batch through the Python API (``run_batch``) and the command line runs its workers
with the same thread settings (one BLAS thread each), so the CPU per take is alike; before, the
API's workers ran multithreaded BLAS and used 2-4 times the command line's CPU."""

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from puppet.fast.blas import ONE_THREAD_ENV

API = """
import json, sys
from puppet.batch import run_batch
takes, engine, address, out = sys.argv[1:-3], *sys.argv[-3:]
report = run_batch(takes, out, formats=("pc2", "gltf"), workers=1, engine=engine,
                   address=address or None)
print(json.dumps([row.cpu_seconds for row in report.rows]))
"""


def run_watching(commands: dict[str, list], outs: dict[str, Path], env, wait_until):
    """Run the batches at once; {name: (its stdout, its first worker's thread count while it
    ran a take: local workers only, None on Ray)}. Each worker is counted the moment its first
    take's staging folder is seen (the worker lives until its batch ends)."""
    batches = {name: subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                      text=True, env=env, cwd=tempfile.gettempdir())
               for name, command in commands.items()}
    threads = {name: None for name in commands if "ray" in commands[name]}

    def counted() -> bool:
        for name, batch in batches.items():
            if name in threads:
                continue
            found = list(outs[name].glob(".puppet-batch.*.partial/t*.*"))
            if found:
                threads[name] = len(os.listdir(f"/proc/{found[0].suffix[1:]}/task"))
            elif batch.poll() is not None:
                threads[name] = None  # ended before a take was seen: compared, and fails
        return len(threads) == len(batches)

    results = {}
    try:
        wait_until(counted, timeout=300, what="a take started in every batch")
        for name, batch in batches.items():
            stdout, stderr = batch.communicate(timeout=900)
            assert batch.returncode == 0, stderr
            results[name] = stdout, threads[name]
    finally:
        for batch in batches.values():
            if batch.poll() is None:
                batch.kill()
                batch.wait()
    return results


@pytest.mark.parametrize("engine", ["local", pytest.param("ray", marks=pytest.mark.skipif(
    __import__("importlib").util.find_spec("ray") is None, reason="ray is not installed"))])
def test_the_python_api_uses_the_command_lines_cpu_per_take(tmp_path, critter, tools, engine,
                                                            wait_until, request):
    # two takes: the first is running when a local worker's threads are counted, and the CPU
    # compared is per take (each 120 readings: the solve, per frame as a BLAS thread pool's
    # cost is, dominates a take's CPU)
    takes = [tools.write_take(tmp_path / f"t{i}.mcap", critter, readings=120, seed=i)
             for i in range(2)]
    # a caller's environment with no thread settings at all: BLAS would take every core
    # Ray: both on the session's cluster (what differs is the driver's environment)
    cluster = request.getfixturevalue("on_ray_cluster") if engine == "ray" else []
    env = {k: v for k, v in os.environ.items() if k not in ONE_THREAD_ENV}
    # both at once: what is compared is each take's own CPU and each worker's threads
    ran = run_watching({"api": [sys.executable, "-P", "-c", API, *map(str, takes), engine,
                                cluster[-1] if cluster else "", str(tmp_path / "api")],
                        "cli": ["puppet", "batch", *map(str, takes), "--out",
                                str(tmp_path / "cli"), "--formats", "pc2,gltf", "--workers",
                                "1", "--engine", engine, "--json", *cluster]},
                       {"api": tmp_path / "api", "cli": tmp_path / "cli"}, env, wait_until)
    (api, api_threads), (cli, cli_threads) = ran["api"], ran["cli"]
    assert api_threads == cli_threads  # no BLAS thread pool of its own in the API's workers
    api_cpu = sum(json.loads(api.splitlines()[-1]))
    cli_cpu = sum(row["cpu_s"] for row in json.loads(cli.splitlines()[0])["takes"])
    assert 0.5 < api_cpu / cli_cpu < 1.6, (api_cpu, cli_cpu)
    for take in takes:
        assert (tmp_path / "api" / f"{take.stem}.pc2").read_bytes() == \
            (tmp_path / "cli" / f"{take.stem}.pc2").read_bytes()
