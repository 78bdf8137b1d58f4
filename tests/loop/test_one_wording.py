"""One name per condition, one wording everywhere: the summary names a servo held this reading
(its reply late or missing) by puppet.events' table alone; the page's legend is the overlay's."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

import puppet
from puppet.events import CONDITIONS, HELD_READING, describe_counts
from puppet.reading import Reading

ROOT = Path(puppet.__file__).parent


class _Solver:
    iterations = solve_ns = iterate_ns = solver_iterations = 0
    renderer = None

    def solve(self, reading):
        pass


def test_a_held_reading_is_named_by_the_table_and_is_not_a_fault():
    from puppet.loop.run import run_frames

    ids = np.array([1, 2])
    readings = [Reading(i, ids, np.zeros(2, np.int32), np.array([True, i != 1])) for i in range(3)]
    summary = run_frames(_Solver(), readings)
    assert summary.faults == {HELD_READING: 1}
    assert set(summary.faults) <= set(CONDITIONS)
    assert not CONDITIONS[HELD_READING].fault
    assert summary.text().splitlines()[-1] == f"faults seen: none; other events: {HELD_READING} 1"
    assert describe_counts({"late_reply": 2, HELD_READING: 2}) == \
        f"none; other events: {HELD_READING} 2, late_reply 2"


def test_the_overlay_legend_and_the_page_use_the_same_name_and_words():
    from puppet.render.overlay import BONE_STATE_COLORS, BONE_STATE_WORDS
    from puppet.view.panel import SERVO_STATES, bone_legend, servo_state

    assert set(BONE_STATE_WORDS) == set(BONE_STATE_COLORS) - {None}
    assert [(i["state"], i["words"]) for i in bone_legend()] == list(BONE_STATE_WORDS.items())
    # a servo at fault: "fault" on the table and on its bone; a late one: no bone state of its own
    assert servo_state(False, True) == "fault" and "fault" in BONE_STATE_WORDS
    assert servo_state(False, False) == "late" and "late" not in BONE_STATE_WORDS
    assert servo_state(True, False) == "ok" and set(SERVO_STATES) == {"ok", "late", "fault"}
    assert "not a fault" in SERVO_STATES["late"]
    js = (ROOT / "view" / "static" / "view.js").read_text()
    assert "setText(row.cells[3], s.state)" in js  # the servo table's state: the panel's name


def test_no_old_name_is_left_in_the_source():
    old = re.compile(r"servo_not_ok|\"faulted\"|'faulted'|: \"flagged\"")
    hits = [f"{p.relative_to(ROOT)}:{n}" for p in ROOT.rglob("*") if p.suffix in (".py", ".js", ".html", ".css")
            for n, line in enumerate(p.read_text().splitlines(), 1) if old.search(line)]
    assert hits == []
