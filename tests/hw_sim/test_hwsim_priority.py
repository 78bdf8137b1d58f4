"""The bus server holds the line: its forked child serves at real-time priority where the system
allows it (servos answer whatever the host's load), and a bus served from a thread leaves the
caller's scheduling alone."""

from __future__ import annotations

import os
import subprocess
import sys

import hw_sim


def _real_time_allowed() -> bool:
    """Whether a process here may take SCHED_RR (root with CAP_SYS_NICE, or an RLIMIT_RTPRIO)."""
    probe = "import os; os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0


def test_the_server_child_serves_at_real_time_priority_where_allowed():
    expected = os.SCHED_RR if _real_time_allowed() else os.SCHED_OTHER
    with hw_sim.serve([1, 2]) as bus:
        assert bus.servo(1).get("ID") == 1  # the child is serving (it has run hold_the_line)
        assert os.sched_getscheduler(bus._worker.pid) == expected
    assert os.sched_getscheduler(0) == os.SCHED_OTHER


def test_a_bus_served_from_a_thread_leaves_the_callers_scheduling_alone():
    before = os.sched_getscheduler(0)
    with hw_sim.serve([1], process=False) as bus:
        assert bus.servo(1).get("ID") == 1
        assert os.sched_getscheduler(0) == before
