"""A batch's policies fail loudly and its failures say what failed: each take's time limit
grows with its length (a swallowed TypeError once gave every take the base), a worker's
unexpected error reaches the take's row and log (the exception, where, the end of its
traceback) on both engines' task paths, and no broad ``except`` in the package swallows an
error without naming it."""

import ast
import dataclasses
from pathlib import Path

import puppet
from puppet.batch.plan import Job
from puppet.batch.task import (TIMEOUT_BASE_S, TIMEOUT_PER_SECOND, Settings, Shared,
                               take_timeout_s)


def test_the_default_take_timeout_grows_with_the_takes_length(tmp_path, critter, tools):
    take = tools.write_take(tmp_path / "long.mcap", critter, readings=121)  # 4 s at 30 per second
    assert take_timeout_s(take, None) == TIMEOUT_BASE_S + TIMEOUT_PER_SECOND * 4.0
    assert take_timeout_s(take, 7.0) == 7.0
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"not a take")
    assert take_timeout_s(broken, None) == TIMEOUT_BASE_S  # a bad take fails at once anyway


def _job_on_a_missing_rig(tmp_path, critter, tools) -> Job:
    take = tools.write_take(tmp_path / "take.mcap", critter)
    return dataclasses.replace(Job(take, {"bvh": tmp_path / "take.bvh"}, tmp_path / "take.log",
                                   tmp_path / "take.manifest.json"), rig_key="no such rig")


def test_a_local_workers_unexpected_error_is_carried_with_its_traceback(tmp_path, critter, tools):
    """A job naming a rig the worker was not sent: a KeyError no take should raise."""
    import pickle

    from puppet.batch.local import LocalEngine

    job = _job_on_a_missing_rig(tmp_path, critter, tools)
    rows = []
    engine = LocalEngine(1)
    staging = tmp_path / "staging"
    staging.mkdir()
    try:
        engine.run([job], pickle.dumps(Shared(rigs={}, settings=Settings(formats=("bvh",)))),
                   staging, lambda _job, row: rows.append(row))
    finally:
        engine.close()
    row, = rows
    assert row.state == "failed"
    assert row.reason.startswith("internal error: KeyError: 'no such rig' (at task.py:")
    assert "the worker's traceback (its end):" in row.log_lines
    assert any("KeyError: 'no such rig'" in line for line in row.log_lines)
    assert "KeyError" in row.log_text()


def test_a_ray_tasks_unexpected_error_is_carried_with_its_traceback(tmp_path, critter, tools):
    """The Ray task's body, run here: its row names the worker's own error, not Ray's wrapper."""
    from puppet.batch.ray_engine import _ray_task

    job = _job_on_a_missing_rig(tmp_path, critter, tools)
    row = _ray_task(job, job.take.read_bytes(), Shared(rigs={}, settings=Settings(formats=("bvh",))),
                    "errors-test")
    assert row.state == "failed" and row.take == str(job.take)
    assert row.reason.startswith("internal error: KeyError: 'no such rig' (at task.py:")
    assert any("KeyError: 'no such rig'" in line for line in row.log_lines)


def _staging_of(name: str) -> None:
    """A worker-side failure outside the take's own run (as a staging folder that cannot be
    made would raise), two calls deep."""
    Path("/dev/null", name).mkdir()


def test_a_ray_task_error_that_crossed_processes_keeps_the_workers_traceback():
    """What ray.get raises in the driver: Ray's own RayTaskError, pickled as it crosses from the
    worker (the cause's __traceback__ stays behind, the traceback comes as text). The row says
    the exception and where the worker raised it; the log holds the traceback's end, not only
    "ray::_ray_task() (pid=..., ip=...)"."""
    import pickle
    import traceback

    import pytest

    exceptions = pytest.importorskip("ray.exceptions")  # the optional extra: 'puppet[ray]'
    from puppet.batch.ray_engine import failed_row

    try:
        _staging_of("take00.4242")
    except OSError as err:
        sent = exceptions.RayTaskError("_ray_task", traceback.format_exc(), err,
                                       proctitle="ray::_ray_task", pid=4242, ip="10.0.0.5")
    got = pickle.loads(pickle.dumps(sent)).as_instanceof_cause()  # as ray.get raises it
    assert got.cause.__traceback__ is None  # what the driver gets: no frames, only the text
    row = failed_row(got, "take00.mcap", tries=1)
    assert row.state == "failed" and row.retries == 0 and row.worker == "10.0.0.5:4242"
    assert row.reason.startswith("the Ray task failed (1 tries): internal error: "
                                 "NotADirectoryError: "), row.reason
    assert row.reason.endswith(" in mkdir)"), row.reason  # where it was raised: pathlib's
    assert "\n" not in row.reason
    assert row.log_lines[0] == "the worker's traceback (its end):"
    assert any("line" in line and "in _staging_of" in line for line in row.log_lines), row.log_lines
    assert row.log_lines[-1].startswith("NotADirectoryError: "), row.log_lines
    assert "NotADirectoryError" in row.log_text()


def _swallowing_handlers(path: Path) -> list[str]:
    """``except Exception`` / ``BaseException`` / bare handlers in a file that neither re-raise
    nor name the error they catch and use that name (report it, hand it on)."""
    found = []
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if not isinstance(node, ast.ExceptHandler):
            continue
        kinds = (node.type.elts if isinstance(node.type, ast.Tuple) else [node.type])
        broad = node.type is None or any(isinstance(k, ast.Name) and k.id in
                                         ("Exception", "BaseException") for k in kinds)
        if not broad:
            continue
        inner = [n for statement in node.body for n in ast.walk(statement)]
        if any(isinstance(n, ast.Raise) for n in inner):
            continue
        if node.name and any(isinstance(n, ast.Name) and n.id == node.name for n in inner):
            continue
        found.append(f"{path}:{node.lineno}")
    return found


def test_no_broad_except_in_the_package_swallows_an_error():
    root = Path(puppet.__file__).parent
    swallowed = [where for path in sorted(root.rglob("*.py")) for where in _swallowing_handlers(path)]
    assert swallowed == []
