"""The same batch through the Python API (``run_batch``) and the command line runs its workers
with the same thread settings (one BLAS thread each), so the CPU per take is alike; before, the
API's workers ran multithreaded BLAS and used 2-4 times the command line's CPU."""

import json
import os
import subprocess
import sys
import tempfile

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


def run_watching(command, out, env, wait_until):
    """Run a batch; (its stdout, its first worker's thread count while it ran a take: local
    workers only, None on Ray)."""
    batch = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=env, cwd=tempfile.gettempdir())
    threads = None
    try:
        if "ray" not in command:
            found = wait_until(lambda: list(out.glob(".puppet-batch.*.partial/t*.*"))
                               or batch.poll() is not None, timeout=300, what="a take started")
            if found is not True:
                threads = len(os.listdir(f"/proc/{found[0].suffix[1:]}/task"))
        stdout, stderr = batch.communicate(timeout=900)
    finally:
        if batch.poll() is None:
            batch.kill()
            batch.wait()
    assert batch.returncode == 0, stderr
    return stdout, threads


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
    api, api_threads = run_watching([sys.executable, "-P", "-c", API, *map(str, takes), engine,
                                     cluster[-1] if cluster else "", str(tmp_path / "api")],
                                    tmp_path / "api", env, wait_until)
    cli, cli_threads = run_watching(["puppet", "batch", *map(str, takes), "--out",
                                     str(tmp_path / "cli"), "--formats", "pc2,gltf", "--workers",
                                     "1", "--engine", engine, "--json", *cluster],
                                    tmp_path / "cli", env, wait_until)
    assert api_threads == cli_threads  # no BLAS thread pool of its own in the API's workers
    api_cpu = sum(json.loads(api.splitlines()[-1]))
    cli_cpu = sum(row["cpu_s"] for row in json.loads(cli.splitlines()[0])["takes"])
    assert 0.5 < api_cpu / cli_cpu < 1.6, (api_cpu, cli_cpu)
    for take in takes:
        assert (tmp_path / "api" / f"{take.stem}.pc2").read_bytes() == \
            (tmp_path / "cli" / f"{take.stem}.pc2").read_bytes()
