"""Bus events (puppet/events.py): the declared kinds are the contract, and the log is bounded."""

import ast
from pathlib import Path

import pytest

import puppet
from puppet.events import EVENT_KINDS, EventLog

SOURCE = Path(puppet.__file__).parent


def _logged_kinds() -> dict[str, list[str]]:
    """{kind: ["file:line", ...]} of every ``<...>log.add(KIND, ...)`` call in puppet/, where KIND
    is a string literal or a conditional choice of literals; AssertionError for any other KIND
    (a kind built at run time would escape the declared list)."""
    found: dict[str, list[str]] = {}
    for path in sorted(SOURCE.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr == "add" and node.args):
                continue
            owner = node.func.value
            name = owner.attr if isinstance(owner, ast.Attribute) else getattr(owner, "id", "")
            if not name.endswith("log"):
                continue
            where = f"{path.relative_to(SOURCE.parent)}:{node.lineno}"
            kind = node.args[0]
            options = [kind.body, kind.orelse] if isinstance(kind, ast.IfExp) else [kind]
            for option in options:
                assert isinstance(option, ast.Constant) and isinstance(option.value, str), (
                    f"{where}: an event kind must be a string literal")
                found.setdefault(option.value, []).append(where)
    return found


def test_every_logged_event_kind_is_declared_and_every_declared_kind_is_logged():
    logged = _logged_kinds()
    undeclared = {kind: where for kind, where in logged.items() if kind not in EVENT_KINDS}
    assert undeclared == {}
    assert sorted(set(EVENT_KINDS) - set(logged)) == []
    assert len(logged) == len(EVENT_KINDS) >= 21


def test_every_kind_has_a_one_line_meaning_and_words_for_a_puppeteer():
    for kind, (meaning, fault, words) in EVENT_KINDS.items():
        assert kind.isidentifier() and kind == kind.lower()
        assert meaning.strip() == meaning and "\n" not in meaning and len(meaning) > 10
        assert isinstance(fault, bool)
        assert words.strip() == words and "\n" not in words and 10 < len(words) <= 80
        assert "_" not in words  # words, not an identifier
    assert EVENT_KINDS["servo_missing"].fault and not EVENT_KINDS["servo_recovered"].fault
    assert not EVENT_KINDS["reconfigured"].fault and not EVENT_KINDS["hardware_error_cleared"].fault


def test_the_summary_line_lists_faults_then_the_other_events():
    from puppet.events import describe_counts

    assert describe_counts({}) == "none"
    assert describe_counts({"servo_recovered": 1, "servo_missing": 2, "held_reading": 5, "late_reply": 5}) == \
        "servo_missing 2; other events: held_reading 5, late_reply 5, servo_recovered 1"
    assert describe_counts({"servo_exploded": 1}) == "servo_exploded 1"  # not in the table: a fault
    assert describe_counts({"quiet": 3}) == "none; other events: quiet 3"


def test_the_log_refuses_an_unknown_kind_naming_it():
    log = EventLog()
    with pytest.raises(ValueError, match="'servo_exploded'"):
        log.add("servo_exploded", [3], "boom")
    assert list(log.events) == [] and log.counts == {}


def test_event_log_is_bounded_and_counts():
    log = EventLog(maxlen=3)
    for i in range(5):
        log.add("servo_failed", [i], "x")
    assert log.counts == {"servo_failed": 5}
    assert [e.ids for e in log.drain()] == [(2,), (3,), (4,)]
    assert log.drain() == []


def test_an_event_from_another_log_keeps_its_time_and_counts():
    child, parent = EventLog(), EventLog()
    event = child.add("port_lost", (), "unplugged")
    for e in child.drain():
        parent.append(e)
    assert list(parent.events) == [event]
    assert parent.counts == {"port_lost": 1}
