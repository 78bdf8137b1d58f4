"""Seeded fuzz of rig files: broken variants of the built-in critter.toml, each given to
``puppet rig info FILE`` as a user would. Every one must end in a clean error: exit 1, an
``Error:`` line naming the file at fault (and the line where the fault has one), no traceback and
no "internal error" (the command line's catch-all for unexpected exceptions).

Cases run in-process through click's CliRunner (fast); a few also run as a real subprocess.
``variants(tmp_path)`` is deterministic: SEED fixes the random picks (which servo, where a text
is cut, which junk bytes).
"""

from __future__ import annotations

import random
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from puppet.cli import main
from puppet.rig.load import BUILTIN_RIG

SEED = 18
CHARACTER = BUILTIN_RIG.parent / "critter.npz"


@dataclass
class Case:
    """One broken rig. text: the rig file's bytes (None: the file is not written). line: the line
    the error must name, or None. names: the file the error must name (default: the rig file).
    files: other files to write next to it."""

    name: str
    text: bytes | None
    line: int | None = None
    names: str | None = None
    files: dict[str, bytes] = field(default_factory=dict)
    rig_name: str = "rig.toml"


def base_lines() -> list[str]:
    """The built-in rig file with its mesh made absolute (the variant lives in a temp folder)."""
    text = BUILTIN_RIG.read_text()
    return text.replace('mesh = "critter.npz"', f'mesh = "{CHARACTER}"').splitlines()


def _sections(lines: list[str]) -> list[tuple[str, int]]:
    """[(table name, header line index)] in file order; the top level is ("", -1)."""
    out = [("", -1)]
    for i, line in enumerate(lines):
        m = re.match(r"^\s*\[\[?\s*([\w.]+)\s*\]\]?", line)
        if m:
            out.append((m.group(1), i))
    return out


def _section_range(lines, table: str, index: int) -> tuple[int, int]:
    """(first, end) line indices of the index-th [table] / [[table]] body (top level: table '')."""
    sections = _sections(lines)
    found = [k for k, (name, _) in enumerate(sections) if name == table]
    k = found[index]
    start = sections[k][1] + 1
    end = sections[k + 1][1] if k + 1 < len(sections) else len(lines)
    return start, end


def set_key(lines, table: str, index: int, key: str, value: str) -> tuple[list[str], int]:
    """Lines with ``key = value`` in the index-th table (replaced, or added after its header);
    and the 1-based line it is on."""
    lines = list(lines)
    start, end = _section_range(lines, table, index)
    for i in range(start, end):
        if re.match(rf"^\s*{re.escape(key)}\s*=", lines[i]):
            lines[i] = f"{key} = {value}"
            return lines, i + 1
    lines.insert(start, f"{key} = {value}")
    return lines, start + 1


def drop_key(lines, table: str, index: int, key: str) -> list[str]:
    start, end = _section_range(lines, table, index)
    return [line for i, line in enumerate(lines)
            if not (start <= i < end and re.match(rf"^\s*{re.escape(key)}\s*=", line))]


def drop_tables(lines, table: str) -> list[str]:
    """Lines without any [[table]] block (and its body)."""
    out, skipping = [], False
    for line in lines:
        m = re.match(r"^\s*\[\[?\s*([\w.]+)\s*\]\]?", line)
        if m:
            skipping = m.group(1) == table
        if not skipping:
            out.append(line)
    return out


def text_of(lines) -> bytes:
    return ("\n".join(lines) + "\n").encode()


def variants(tmp_path: Path) -> list[Case]:
    rng = random.Random(SEED)
    base = base_lines()
    servo = rng.randrange(15)  # the servo whose fields are broken
    cases: list[Case] = []

    def servo_field(name, key, value, at_table=False):
        lines, line = set_key(base, "servo", servo, key, value)
        if at_table:  # found once the skeleton is known: the error names the servo's table
            line = _section_range(lines, "servo", servo)[0]
        cases.append(Case(name, text_of(lines), line))

    for name, value in [("nan", "[nan, 0, 0]"), ("inf", "[inf, 0, 0]"), ("-inf", "[0, -inf, 1]"),
                        ("overflowing float", "[1e309, 0, 0]"), ("zero", "[0, 0, 0]"),
                        ("unknown name", '"w"'), ("two numbers", "[1, 0]"), ("bool", "true"),
                        ("table", "{ x = 1 }"), ("strings", '["1", "0", "0"]')]:
        servo_field(f"axis {name}", "axis", value)
    for name, value in [("nan", "nan"), ("inf", "inf"), ("zero", "0"), ("negative", "-1.0"),
                        ("huge", "1e9"), ("tiny", "1e-9"), ("string", '"2"'), ("bool", "false")]:
        servo_field(f"gear {name}", "gear", value)
    for name, value in [("nan", "nan"), ("float", "2048.5"), ("huge", "99999999999999999999"),
                        ("int64 min", "-9223372036854775808"), ("string", '"2048"')]:
        servo_field(f"zero_ticks {name}", "zero_ticks", value)
    for name, value in [("nan", "[nan, 40]"), ("inf", "[-inf, inf]"), ("reversed", "[40, -40]"),
                        ("empty", "[10, 10]"), ("huge", "[-1e6, 1e6]"), ("three", "[1, 2, 3]"),
                        ("not a list", "45")]:
        servo_field(f"limits_deg {name}", "limits_deg", value)
    for name, key, value in [("order 0", "order", "0"), ("order 9", "order", "9"),
                             ("order nan", "order", "nan"), ("sign 0", "sign", "0"),
                             ("sign float", "sign", "1.0"), ("sign nan", "sign", "nan"),
                             ("id 300", "id", "300"), ("id -1", "id", "-1"),
                             ("id nan", "id", "nan"), ("id string", "id", '"1"'),
                             ("model unknown", "model", '"XC330-M999"'),
                             ("model list", "model", '["XL330-M288"]'),
                             ("model int", "model", "1200"),
                             ("joint int", "joint", "7"), ("unknown key", "colour", '"red"')]:
        servo_field(f"servo {name}", key, value)
    servo_field("servo joint unknown", "joint", '"no_such_bone"', at_table=True)
    # id 2 repeated: the error names the second servo's table.
    lines, _ = set_key(base, "servo", 1, "id", "1")
    cases.append(Case("duplicate id", text_of(lines), _section_range(lines, "servo", 1)[0]))
    # Four servos on the head joint (orders 1..3 are all a joint may have).
    lines = list(base)
    for k, order in zip(range(4), (1, 2, 3, 3)):
        lines, _ = set_key(lines, "servo", k, "joint", '"head"')
        lines, _ = set_key(lines, "servo", k, "order", str(order))
    cases.append(Case("four servos on one joint", text_of(lines), _section_range(lines, "servo", 3)[0]))
    lines, _ = set_key(base, "servo", 2, "order", "1")  # servos 2 and 3 both order 1 on "head"
    cases.append(Case("repeated order on a joint", text_of(lines), _section_range(lines, "servo", 2)[0]))

    for name, value in [("negative", "-1"), ("out of range", "100000000"), ("nan", "nan"),
                        ("float", "3.5")]:
        lines, line = set_key(base, "pin", 0, "vertex", value)
        cases.append(Case(f"pin vertex {name}", text_of(lines), line))
    for name, value in [("nan", "[nan, 0, 0]"), ("inf", "[inf, 0, 0]"), ("short", "[0, 1]")]:
        lines = drop_key(base, "pin", 0, "vertex")
        lines, line = set_key(lines, "pin", 0, "point", value)
        cases.append(Case(f"pin point {name}", text_of(lines), line))
    lines = drop_key(base, "pin", 0, "vertex")
    cases.append(Case("pin empty", text_of(lines), _section_range(lines, "pin", 0)[0]))
    lines, _ = set_key(base, "pin", 0, "point", "[0, 0, 0]")
    cases.append(Case("pin vertex and point", text_of(lines), _section_range(lines, "pin", 0)[0]))
    lines = base + ["[[pin]]", "vertex = 12279"]
    cases.append(Case("pin twice", text_of(lines), len(lines)))

    for name, key, value in [("clusters huge", "clusters", "100000000"),
                             ("clusters zero", "clusters", "0"), ("clusters nan", "clusters", "nan"),
                             ("clusters float", "clusters", "100.0"),
                             ("extra_weights huge", "extra_weights", "1000000000"),
                             ("extra_weights negative", "extra_weights", "-1"),
                             ("energy unknown", "energy", '"nope"'), ("energy int", "energy", "3"),
                             ("unknown option", "iterations", "10")]:
        lines, line = set_key(base, "solver", 0, key, value)
        cases.append(Case(f"solver {name}", text_of(lines), line))
    # More clusters than the mesh has vertices (within the file's own bound).
    lines, line = set_key(base, "solver", 0, "clusters", "5000")
    small = tmp_path / "small.npz"
    with np.load(CHARACTER) as data:
        arrays = {k: data[k] for k in data.files}
    keep = arrays["F"][:50]
    used = np.unique(keep)
    remap = np.full(len(arrays["V"]), -1)
    remap[used] = np.arange(len(used))
    np.savez(small, **{**arrays, "V": arrays["V"][used], "W": arrays["W"][used], "F": remap[keep]})
    lines = [f'mesh = "{small}"' if line.startswith("mesh =") else line for line in lines]
    lines = drop_tables(lines, "pin") + ["[[pin]]", "vertex = 0"]
    cases.append(Case("clusters above vertex count", text_of(lines), line))

    for name, value in [("unknown bone", '["nope"]'), ("string", '"hips"'), ("twice", '["hips", "hips"]'),
                        ("ints", "[1]")]:
        lines, line = set_key(base, "", 0, "fixed", value)
        cases.append(Case(f"fixed {name}", text_of(lines), line))
    lines = drop_tables(drop_key(base, "", 0, "fixed"), "pin")
    cases.append(Case("free root, no pin", text_of(lines)))

    for name, value, names in [("missing file", '"missing.npz"', "missing.npz"),
                               ("empty string", '""', None), ("int", "5", None),
                               ("nul", '"a\\u0000b.npz"', None), ("unknown suffix", '"body.fbx"', None)]:
        lines, line = set_key(base, "", 0, "mesh", value)
        cases.append(Case(f"mesh {name}", text_of(lines), None if names else line, names))
    cases.append(Case("mesh key missing", text_of(drop_key(base, "", 0, "mesh"))))
    for name, data in [("empty", b""), ("short junk", b"glTF\x02\x00"),
                       ("random junk", bytes(rng.randrange(256) for _ in range(64)))]:
        glb = f"{name.replace(' ', '_')}.glb"
        lines, _ = set_key(base, "", 0, "mesh", f'"{glb}"')
        cases.append(Case(f"glb {name}", text_of(lines), names=glb, files={glb: data}))
    lines, _ = set_key(base, "", 0, "mesh", '"folder.npz"')
    (tmp_path / "folder.npz").mkdir()
    cases.append(Case("mesh is a folder", text_of(lines), names="folder.npz"))
    nan_npz = tmp_path / "nan.npz"
    V = arrays["V"].copy()
    V[7] = np.nan
    np.savez(nan_npz, **{**arrays, "V": V})
    lines, _ = set_key(base, "", 0, "mesh", f'"{nan_npz}"')
    cases.append(Case("character with a NaN vertex", text_of(lines), names="nan.npz"))
    lines, _ = set_key(base, "", 0, "mesh", '"junk.npz"')
    cases.append(Case("character npz junk", text_of(lines), names="junk.npz",
                      files={"junk.npz": b"PK\x03\x04 not really a zip"}))

    for name, body in [("nan", "[zero_ticks]\n1 = nan\n"), ("huge", "[zero_ticks]\n1 = 99999999999\n"),
                       ("bad id", "[zero_ticks]\nx = 5\n"), ("junk", "]]]\n")]:
        lines, _ = set_key(base, "", 0, "calibration", '"cal.toml"')
        cases.append(Case(f"calibration {name}", text_of(lines), names="cal.toml",
                          files={"cal.toml": body.encode()}))

    lines, line = set_key(base, "", 0, "colour", '"red"')
    cases.append(Case("unknown top-level key", text_of(lines), line))
    lines, line = set_key(base, "", 0, "name", "5")
    cases.append(Case("name int", text_of(lines), line))
    lines, line = set_key(base, "", 0, "servo", "3")
    cases.append(Case("servo not tables", text_of(drop_tables(lines, "servo")), line))
    lines, line = set_key(drop_tables(base, "solver"), "", 0, "solver", "5")
    cases.append(Case("solver not a table", text_of(lines), line))
    lines = base[:2] + ['name = "again"'] + base[2:]
    cases.append(Case("duplicate key", text_of(lines), 3))
    cases.append(Case("deep array", text_of(base[:3] + ["deep = " + "[" * 100000 + "]" * 100000])))
    cases.append(Case("deep inline table", text_of(base[:3] + ["deep = " + "{a = " * 20000 + "1" + "}" * 20000])))
    cases.append(Case("deep dotted table", text_of(base + ["[" + ".".join(["a"] * 20000) + "]"]),
                      len(base) + 1))
    full = text_of(base)
    quoted = [i for i, line in enumerate(base) if '"' in line and not line.startswith("#")]
    for i in rng.sample(quoted, 3):  # cut inside a quoted value: an unterminated string
        cut = len(text_of(base[:i])) + base[i].index('"') + 2
        cases.append(Case(f"truncated at byte {cut}", full[:cut], i + 1))
    for k in range(2):
        cases.append(Case(f"binary junk {k}", bytes(rng.randrange(256) for _ in range(200))))
    cases.append(Case("NUL byte", full[:100] + b"\x00" + full[100:]))
    cases.append(Case("latin-1 text", full.replace(b'"critter"', '"crïtter"'.encode("latin-1"))))
    cases.append(Case("empty file", b""))
    cases.append(Case("rig file missing", None))
    cases.append(Case("rig file is a folder", None, rig_name="folder.toml"))
    (tmp_path / "folder.toml").mkdir()
    return cases


def write_case(case: Case, folder: Path) -> Path:
    """Write the case's files into ``folder``; the rig file's path."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in case.files.items():
        (folder / name).write_bytes(data)
    path = folder / case.rig_name
    if case.text is not None:
        path.write_bytes(case.text)
    return path


def check_clean(case: Case, path: Path, exit_code: int, stderr: str) -> None:
    """The contract: exit 1, one Error: line naming the file (and the line), no traceback."""
    assert "Traceback" not in stderr, (case.name, stderr[-2000:])
    assert "internal error" not in stderr, (case.name, stderr)
    assert exit_code == 1, (case.name, exit_code, stderr)
    errors = [line for line in stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1, (case.name, stderr)
    named = case.names or str(path)
    assert named in errors[0], (case.name, named, errors[0])
    if case.line is not None:
        assert f"{path}:{case.line}:" in errors[0], (case.name, case.line, errors[0])


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz_rigs")
    return folder, variants(folder)


def test_there_are_at_least_forty_distinct_variants(cases):
    _, found = cases
    assert len(found) >= 40
    assert len({c.name for c in found}) == len(found)
    inputs = {(c.text, tuple(sorted(c.files.items())), c.rig_name) for c in found}
    assert len(inputs) == len(found)


def test_every_broken_rig_is_a_clean_error_in_process(cases):
    folder, found = cases
    runner = CliRunner()
    for case in found:
        path = write_case(case, folder)
        result = runner.invoke(main, ["rig", "info", str(path)])
        assert result.exception is None or isinstance(result.exception, SystemExit), \
            (case.name, repr(result.exception))
        check_clean(case, path, result.exit_code, result.stderr)


@pytest.mark.parametrize("name", ["axis nan", "deep array", "binary junk 0", "free root, no pin",
                                  "glb empty"])
def test_a_few_broken_rigs_as_a_real_command(cases, name):
    folder, found = cases
    case = next(c for c in found if c.name == name)
    path = write_case(case, folder)
    result = subprocess.run([sys.executable, "-P", "-c", "from puppet.cli import main; main()",
                             "rig", "info", str(path)], capture_output=True, text=True, timeout=120)
    check_clean(case, path, result.returncode, result.stderr)


def classify(case: Case, path: Path, command: list[str]) -> str:
    """One case run as a real command: clean | traceback | hang | silent wrong | vague error."""
    try:
        result = subprocess.run([*command, "rig", "info", str(path)], capture_output=True,
                                text=True, timeout=60)
    except subprocess.TimeoutExpired:
        return "hang"
    if "Traceback" in result.stderr or "internal error" in result.stderr:
        return "traceback"
    if result.returncode == 0:
        return "silent wrong"
    try:
        check_clean(case, path, result.returncode, result.stderr)
    except AssertionError:
        return "vague error"  # exit 1, but the file or the line is not named
    return "clean"


if __name__ == "__main__":
    # The before/after table: python tests/fuzz/test_fuzz_rigs.py [PUPPET_COMMAND...]
    # (default: this interpreter's puppet; pass another checkout's command to compare).
    import collections
    import tempfile

    command = sys.argv[1:] or [sys.executable, "-P", "-c", "from puppet.cli import main; main()"]
    folder = Path(tempfile.mkdtemp(prefix="fuzz_rigs_"))
    outcomes = collections.Counter()
    for case in variants(folder):
        outcome = classify(case, write_case(case, folder), command)
        outcomes[outcome] += 1
        if outcome != "clean":
            print(f"{outcome:13} {case.name}")
    print(dict(outcomes), f"of {sum(outcomes.values())} cases")
