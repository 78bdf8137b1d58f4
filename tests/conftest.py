"""Session-wide test setup: a private cache folder, waiting for a condition, and the real
dynamixel_sdk opened on a simulated bus's port (``open_sdk``, for tests/hw_sim and tests/drive).

Tests never write to the user's cache: ``PUPPET_CACHE`` points into a temporary folder for
the whole session (subprocesses started by tests inherit it).

Tests on a loaded 2-core machine must not depend on speed: instead of sleeping a fixed time
and then asserting a state, they wait for the state with ``wait_until`` and a generous timeout.

The suite runs in parallel workers (pytest-xdist, ``-n 3 --dist loadgroup`` in pyproject.toml).
Tests that share an expensive set-up or a resource run in one worker (``xdist_group``, set here
at collection: see ``XDIST_GROUPS`` and ``_xdist_group``). At the end of a run pytest prints the
25 slowest tests and the time per top-level folder (``pytest_terminal_summary``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import dynamixel_sdk
import pytest

# Tests stop subprocesses with Ctrl-C (SIGINT). A shell that starts a command with `cmd &` and no
# job control starts it with SIGINT ignored, Python then installs no KeyboardInterrupt handler,
# and every subprocess inherits the ignore: the test would wait on a process deaf to Ctrl-C.
# A handled SIGINT here resets to the default in every child at exec.
signal.signal(signal.SIGINT, signal.default_int_handler)

# Subprocesses that tests start with ``python -c`` run in the checkout's root: without this, the
# current folder comes first on their path and they import the source tree, which has no built
# native modules (puppet._native, puppet._kinematics) when the package is installed normally
# (CI's `pip install .`), instead of the installed package. PYTHONSAFEPATH (Python >= 3.11)
# leaves the current folder off their path.
os.environ["PYTHONSAFEPATH"] = "1"

PATIENCE_S = 60.0
"""How long a test waits for a condition that a quiet machine meets in milliseconds."""

T = TypeVar("T")


def wait_until(predicate: Callable[[], T], timeout: float = PATIENCE_S, interval: float = 0.01,
               what: str = "condition") -> T:
    """Call ``predicate`` until it returns a true value (returned); AssertionError naming
    ``what`` when ``timeout`` seconds pass first."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not reached within {timeout} s")
        time.sleep(interval)


def _interrupt_and_wait(proc: subprocess.Popen, timeout: float = PATIENCE_S,
                        read_stderr: bool = True) -> int:
    """Ctrl-C ``proc`` and wait for its exit code. If it has not exited within ``timeout`` s,
    AssertionError with what it was doing: its kernel state and wait channel, and (hw-sim
    dumps its threads' stacks on SIGUSR1) its Python stacks on stderr; it is killed after.
    ``read_stderr``: add the end of its stderr pipe to the message (False when a thread of the
    caller reads that pipe)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        report = _stuck_report(proc.pid)
        proc.send_signal(signal.SIGUSR1)
        time.sleep(1.0)  # a diagnostic pause, not a wait for a state
        proc.kill()
        proc.wait()
        err = proc.stderr.read()[-3000:] if read_stderr and proc.stderr is not None else ""
        raise AssertionError(f"pid {proc.pid} still running {timeout} s after Ctrl-C: {report}"
                             f"\n{err}")


def _stuck_report(pid: int) -> str:
    """One line on where process ``pid`` is: State and wchan from /proc (what is readable)."""
    parts = []
    for name in ("status", "wchan", "stack"):
        try:
            with open(f"/proc/{pid}/{name}") as fh:
                text = fh.read()
        except OSError as exc:
            parts.append(f"{name}: {exc.strerror}")
            continue
        if name == "status":
            text = next((line for line in text.splitlines() if line.startswith("State")), "")
        parts.append(f"{name}: {text.strip()}")
    return "; ".join(parts)


def group_gone(group: int) -> bool:
    """True once every process of process group ``group`` has exited. One left as a zombie has
    exited: only its reaper has not collected it yet (an orphan's is init, which does so in its
    own time: multiprocessing's resource tracker outlives the command by a moment and ends on
    its own, then waits as a zombie for init)."""
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return True
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            state, _, pgid = (entry / "stat").read_text().rsplit(")", 1)[1].split()[:3]
        except (OSError, ValueError):  # gone meanwhile
            continue
        if int(pgid) == group and state != "Z":
            return False
    return True


@pytest.fixture(name="interrupt_and_wait")
def _interrupt_and_wait_fixture():
    return _interrupt_and_wait


@pytest.fixture(name="wait_until")
def _wait_until_fixture():
    return wait_until


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory):
    """PUPPET_CACHE -> a temporary folder for the session (never the user's home cache)."""
    folder = tmp_path_factory.mktemp("puppet-cache")
    saved = os.environ.get("PUPPET_CACHE")
    os.environ["PUPPET_CACHE"] = str(folder)
    yield folder
    if saved is None:
        os.environ.pop("PUPPET_CACHE", None)
    else:
        os.environ["PUPPET_CACHE"] = saved


SDK_BAUD = 1_000_000
SDK_RETRIES = 5
"""Tries of an Sdk transaction whose reply a stalled machine delayed past the SDK's deadline."""


class Sdk:
    """The unmodified SDK on a simulated bus: ``port`` (PortHandler), ``packet``
    (``PacketHandler(protocol)``, Protocol 2.0 unless told).

    write/read_status/read4 retry a transaction whose reply was lost SDK_RETRIES times (the
    deadline is the SDK's LATENCY_TIMER, which each folder's conftest sets)."""

    def __init__(self, path: str, protocol: float = 2.0) -> None:
        self.port = dynamixel_sdk.PortHandler(path)
        assert self.port.openPort() is True
        assert self.port.setBaudRate(SDK_BAUD) is True
        self.packet = dynamixel_sdk.PacketHandler(protocol)

    def _answered(self, call, what: str) -> tuple:
        """call() -> an SDK result tuple (..., result code, status error byte), tried up to
        SDK_RETRIES times until its code is COMM_SUCCESS; AssertionError naming ``what``."""
        for _ in range(SDK_RETRIES):
            result = call()
            if result[-2] == dynamixel_sdk.COMM_SUCCESS:
                return result
        raise AssertionError(f"{what}: no reply in {SDK_RETRIES} tries")

    def write(self, dxl_id: int, addr: int, size: int, value: int) -> int:
        """Write ``size`` (1, 2 or 4) bytes and return the status error number. A reply lost to
        a stalled machine is retried (every write in the tests sets an absolute value, so a
        repeat is harmless)."""
        fn = {1: self.packet.write1ByteTxRx, 2: self.packet.write2ByteTxRx,
              4: self.packet.write4ByteTxRx}[size]
        data = value & ((1 << (8 * size)) - 1)
        _, error = self._answered(lambda: fn(self.port, dxl_id, addr, data),
                                  f"write to servo {dxl_id} address {addr}")
        return error & 0x7F

    def read_status(self, dxl_id: int, addr: int) -> int:
        """The status error byte (alert bit included) of a 1-byte read, retried like write."""
        _, _, error = self._answered(lambda: self.packet.read1ByteTxRx(self.port, dxl_id, addr),
                                     f"read of servo {dxl_id} address {addr}")
        return error

    def read2(self, dxl_id: int, addr: int) -> int:
        """A 2-byte value, retried like write."""
        value, _, _ = self._answered(lambda: self.packet.read2ByteTxRx(self.port, dxl_id, addr),
                                     f"read of servo {dxl_id} address {addr}")
        return value

    def read4(self, dxl_id: int, addr: int) -> int:
        """A 4-byte value, retried like write."""
        value, _, _ = self._answered(lambda: self.packet.read4ByteTxRx(self.port, dxl_id, addr),
                                     f"read of servo {dxl_id} address {addr}")
        return value

    def close(self) -> None:
        if self.port.is_open:
            self.port.closePort()


@pytest.fixture
def open_sdk():
    """Factory: ``open_sdk(path, protocol=2.0)`` -> Sdk opened on that port; all closed after
    the test."""
    opened = []

    def make(path: str, protocol: float = 2.0) -> Sdk:
        sdk = Sdk(path, protocol)
        opened.append(sdk)
        return sdk

    yield make
    for sdk in opened:
        sdk.close()


@pytest.fixture
def protocol1_rig(tmp_path):
    """Path of the built-in critter on a Protocol 1.0 bus (critter_ax.toml: servos 1..8 AX-12A,
    zero ticks 511..518, about the middle of its 0..1023; 9..15 MX-28), its mesh made absolute,
    written into the test's folder."""
    from puppet.rig.load import BUILTIN_AX_RIG

    path = tmp_path / "critter_p1.toml"
    path.write_text(BUILTIN_AX_RIG.read_text().replace(
        'mesh = "critter.npz"', f'mesh = "{BUILTIN_AX_RIG.parent / "critter.npz"}"'))
    return path


# -- parallel runs (pytest-xdist) ---------------------------------------------------------------

XDIST_GROUPS = {
    # one Blender set-up per character: mare_shown and the fixtures built on it here, the
    # tests of critter_shown (the param "critter" of the fixture shown) in their own group
    "tests/export/blender/": "blender-export",
    # tests that load the host on purpose (busy processes beside the bus) or time a bus under
    # load: one at a time, never two of them stacked on each other
    "tests/drive/test_perform_busy.py": "host-load",
    "tests/bus/test_bus_under_load.py": "host-load",
    "tests/bus/test_bus_scan.py": "host-load",
}
"""Path prefix (relative to the repository) -> xdist group: tests that share a session set-up
run in one worker, so it is made once."""

SHARED_FIXTURES = {
    "serial_outputs": "batch-serial",  # the serial exports every batch engine is compared with
    "ray_cluster": "batch-ray",  # the session's Ray cluster (tests/batch/conftest.py)
}
"""Fixture -> xdist group: the tests that use an expensive session fixture run in one worker."""

RAY_GROUP = "batch-ray"
"""The tests that start Ray (a test run with ``engine == "ray"``, or marked with this group):
one Ray instance at a time on the machine."""


def _xdist_group(item: pytest.Item, path: str) -> str | None:
    """The worker group of a test: XDIST_GROUPS by path, Ray's tests together, SHARED_FIXTURES,
    else its module when it uses a module-scoped fixture (made once, in one worker); None: any
    worker."""
    callspec = getattr(item, "callspec", None)
    params = callspec.params if callspec is not None else {}
    if path.startswith("tests/export/blender/") and params.get("shown") == "critter":
        return "blender-export-critter"  # critter_shown's Blender run beside the mare's
    for prefix, group in XDIST_GROUPS.items():
        if path.startswith(prefix):
            return group
    if params.get("engine") == "ray":
        return RAY_GROUP
    for name in getattr(item, "fixturenames", ()):
        if name in SHARED_FIXTURES:
            return SHARED_FIXTURES[name]
    info = getattr(item, "_fixtureinfo", None)
    if info is not None:
        for defs in info.name2fixturedefs.values():
            if defs and defs[-1].scope == "module":
                return path
    return None


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config, items):
    """Mark each test's xdist group before every other hook (xdist's reads the marks), and after
    them give the node id its group suffix where xdist's own could not (pytest >= 9.2 keeps the
    node id in ``_id``: xdist 3.8 still sets ``_nodeid``, and loadgroup then groups nothing)."""
    root = Path(str(config.rootpath))
    for item in items:
        if item.get_closest_marker("xdist_group") is not None:
            continue  # the test says so itself
        try:
            path = Path(str(item.path)).relative_to(root).as_posix()
        except ValueError:
            continue
        group = _xdist_group(item, path)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))
    result = yield
    if getattr(config.option, "loadgroup", False):  # set in xdist workers only
        for item in items:
            names = sorted({str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
                            for mark in item.iter_markers("xdist_group")})
            if names and "@" not in item.nodeid and hasattr(item, "_id"):
                from _pytest.nodeid import coerce_node_id

                item._id = coerce_node_id(f"{item.nodeid}@{'_'.join(names)}")
    return result


def _folder(nodeid: str) -> str:
    """The top-level test folder of a node id ("tests/loop/test_x.py::t" -> "loop")."""
    parts = nodeid.split("::")[0].split("/")
    if parts[0] == "tests":
        parts = parts[1:]
    return parts[0] if len(parts) > 1 else "(top)"


@pytest.hookimpl(trylast=True)  # after the slowest-tests table
def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """The suite's time per top-level folder (set-up, call and tear-down of every test, summed
    over workers: with -n the sum exceeds the wall time), slowest first."""
    if hasattr(config, "workerinput"):
        return  # an xdist worker: its reports reach the controller, which prints
    seconds: dict[str, float] = defaultdict(float)
    tests: dict[str, set] = defaultdict(set)
    for reports in terminalreporter.stats.values():
        for report in reports:
            duration = getattr(report, "duration", None)
            nodeid = getattr(report, "nodeid", "")
            if duration is None or not nodeid or getattr(report, "when", None) is None:
                continue
            folder = _folder(nodeid)
            seconds[folder] += duration
            tests[folder].add(nodeid)
    if not seconds:
        return
    terminalreporter.write_sep("=", "time per folder (set-up + call + tear-down, all workers)")
    for folder, total in sorted(seconds.items(), key=lambda kv: -kv[1]):
        terminalreporter.write_line(f"{total:9.1f} s  {len(tests[folder]):5d} tests  {folder}")
    terminalreporter.write_line(f"{sum(seconds.values()):9.1f} s  "
                                f"{sum(map(len, tests.values())):5d} tests  (all)")
