"""Every number a user can give, drawn from the hostile set (seeded, deterministic).

Each numeric rig-file field, fault-file parameter and command-line option gets each value of
{0, -0, tiny, huge, +inf, -inf, nan, negative, the type's max}. Every case must end, within a
generous time bound, in a clean error naming the field (RigError / FaultFileError / click's
"Invalid value for '--option'"), or in a correct run: the rig loads and solves frames with finite
vertices; the fault runs on a simulated servo with finite readings; the option parses to a value
inside the Range its help text documents (puppet.limits).

``python tests/fuzz/test_fuzz_values.py`` prints the case table (outcome counts per source); run
it with another checkout's interpreter for a before/after comparison.
"""

from __future__ import annotations

import collections
import math
import random
import re
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

SEED = 26
BOUND_S = 120.0  # per case: generous on a loaded 2-core machine; a hang is far beyond it
ABSURD = ("huge", "+inf", "-inf", "nan", "max")  # no documented range holds these

# The hostile values: (label, TOML / command-line text, Python value).
VALUES = [
    ("0", "0", 0),
    ("-0", "-0.0", -0.0),
    ("tiny", "5e-324", 5e-324),
    ("huge", "1e308", 1e308),
    ("+inf", "inf", math.inf),
    ("-inf", "-inf", -math.inf),
    ("nan", "nan", math.nan),
    ("negative", "-1", -1),
    ("max", "9223372036854775807", 2**63 - 1),
]

# Rig-file fields: (field named in the error, how the value is written into the rig text).
# "key": replace the first ``key = ...`` line (the [solver], [solver.dynamics] or first
# [[servo]] key); "top": a top-level key; "table": a table appended at the end ({} = the value).
RIG_FIELDS = [
    ("dropout_ms", "top", "dropout_ms = {}"),
    ("dropout_blend_frames", "top", "dropout_blend_frames = {}"),
    ("skin", "top", "skin = {}"),
    ("solver.clusters", "key", "clusters"),
    ("solver.extra_weights", "key", "extra_weights"),
    ("solver.dynamics.density", "key", "density"),
    ("solver.dynamics.damping", "key", "damping"),
    ("solver.dynamics.dt", "key", "dt"),
    ("solver.dynamics.max_steps", "key", "max_steps"),
    ("solver.dynamics.gravity", "table-dyn", "gravity = [0, {}, 0]"),
    ("servo 1 gear", "key", "gear"),
    ("servo 1 zero_ticks", "key", "zero_ticks"),
    ("servo 1 order", "key", "order"),
    ("servo 1 sign", "key", "sign"),
    ("servo 1 limits_deg", "key-list", "limits_deg = [{}, 40]"),
    ("servo 1 axis", "key-list", "axis = [{}, 1, 0]"),
    ("servo #1 id", "key", "id"),
    ("contact 1 value", "table", '[[contact]]\nvertex = 3\naxes = "y"\nvalue = {}'),
    ("contact 1 vertex", "table", '[[contact]]\nvertex = {}\naxes = "y"'),
    ("contact 1 point", "table", '[[contact]]\npoint = [-0.448, 0.433, {}]\naxes = "y"'),  # near vertex 3 (arm)
    ("pin", "table", "[[pin]]\nvertex = {}"),
    ("pin #2 point", "table", "[[pin]]\npoint = [{}, 0, 0]"),  # the rig has one pin
    ("limit 1 swing_deg", "table", '[[limit]]\nbone = "spine"\nswing_deg = {}'),
    ("limit 1 twist_deg", "table", '[[limit]]\nbone = "spine"\ntwist_deg = [{}, 10]'),
]


def base_rig_text() -> str:
    from puppet.rig.load import BUILTIN_DYNAMICS_RIG

    text = BUILTIN_DYNAMICS_RIG.read_text()
    mesh = BUILTIN_DYNAMICS_RIG.parent / "critter.npz"
    return text.replace('mesh = "critter.npz"', f'mesh = "{mesh}"')


def rig_text(base: str, how: str, spec: str, value: str) -> str:
    if how == "top":
        return spec.format(value) + "\n" + base
    if how == "key":
        text, n = re.subn(rf"(?m)^{re.escape(spec)} = .*$", f"{spec} = {value}", base, count=1)
        assert n == 1, spec
        return text
    if how == "key-list":
        key = spec.split(" ")[0]
        text, n = re.subn(rf"(?m)^{key} = .*$", spec.format(value), base, count=1)
        assert n == 1, spec
        return text
    if how == "table-dyn":
        return base.replace("[solver.dynamics]", "[solver.dynamics]\n" + spec.format(value), 1)
    return base + "\n" + spec.format(value) + "\n"


class _Overtime(Exception):
    pass


def _bounded(run):
    """run() under a wall-time bound (SIGALRM: in-process, main thread); 'hang' past it."""
    def alarm(_signum, _frame):
        raise _Overtime

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, BOUND_S)
    try:
        return run()
    except _Overtime:
        return "hang"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def solve_frames(rig, frames: int = 6) -> bool:
    """Solve a few frames of the demo performance; True when every vertex stays finite."""
    from puppet.bus import Reading
    from puppet.demo import Performance
    from puppet.loop import Pipeline, run_frames

    perf = Performance(rig)
    ids = np.array([s.id for s in rig.servo_map.servos])
    reads = [Reading(int(f / 30 * 1e9), ids,
                     np.array([perf.position(i, f / 30) for i in ids]).round().astype(np.int32),
                     np.ones(len(ids), bool)) for f in range(frames)]
    out = []
    with Pipeline(rig, render=False) as pipeline:
        M = pipeline.model.lbs_matrix()
        run_frames(pipeline, reads, on_frame=lambda p: out.append(M @ p.T))
    return len(out) == frames and bool(np.isfinite(np.array(out)).all())


def rig_case(folder: Path, base: str, field: str, how: str, spec: str, label: str, text: str) -> str:
    """One rig-file case: clean | correct run | vague error | internal error | late error |
    absurd accepted | silent wrong | hang."""
    from puppet.errors import PuppetError
    from puppet.rig.errors import RigError
    from puppet.rig.load import load_rig

    path = folder / "rig.toml"
    path.write_text(rig_text(base, how, spec, text))

    def run():
        try:
            rig = load_rig(path)
        except RigError as err:
            return "clean" if field in str(err) and str(path) in str(err) else "vague error"
        except Exception:  # noqa: BLE001 - what the user would see as an internal error
            return "internal error"
        if label in ABSURD:
            return "absurd accepted"
        try:
            return "correct run" if solve_frames(rig) else "silent wrong"
        except PuppetError:
            return "late error"
        except Exception:  # noqa: BLE001
            return "internal error"

    return _bounded(run)


def rig_cases():
    rng = random.Random(SEED)
    cases = [(field, how, spec, label, text) for field, how, spec in RIG_FIELDS
             for label, text, _ in VALUES]
    rng.shuffle(cases)
    return cases


# Fault-file parameters: every numeric parameter of every kind, plus start time and duration.
def fault_cases():
    from hw_sim.faults import KINDS

    cases = []
    for kind, params in KINDS.items():
        for name, (typ, _) in params.items():
            if typ in (int, float):
                cases += [(f"{kind} {name}", f"0.5 {kind} ids=1 {name}={{}}", name)]
    cases += [("start time", "{} drop ids=1", "start time"), ("duration", "0.5 drop ids=1 for={}", "duration")]
    return [(what, line, word, label, text) for what, line, word in cases for label, text, _ in VALUES]


def fault_case(folder: Path, line: str, word: str, label: str, text: str) -> str:
    from hw_sim.errors import FaultFileError
    from hw_sim.faults import FaultSchedule
    from hw_sim.server import Server

    path = folder / "faults.txt"
    path.write_text("# header\n" + line.format(text) + "\n")

    def run():
        try:
            schedule = FaultSchedule.from_file(path)
        except FaultFileError as err:
            return "clean" if word in str(err) and f"{path}:2" in str(err) else "vague error"
        except Exception:  # noqa: BLE001
            return "internal error"
        if label in ABSURD:
            return "absurd accepted"
        try:
            server = Server({1: "XL330-M288", 2: "XL330-M288"}, faults=schedule)
        except Exception:  # noqa: BLE001
            return "internal error"
        try:
            fault = schedule.faults[0]
            numbers = [fault.start_s, fault.duration_s or 0.0,
                       *(v for v in fault.params.values() if isinstance(v, (int, float)))]
            if not all(math.isfinite(v) for v in numbers):
                return "silent wrong"
            for now in (0.0, 0.6, 1.0, 3.0):
                server.advance(now)
                for servo in server.bus.servos:
                    servo.refresh(now)
                    readings = [servo.get("Present Position"), servo.get("Present Temperature")]
                    if not all(math.isfinite(r) for r in readings):
                        return "silent wrong"
            return "correct run"
        except Exception:  # noqa: BLE001
            return "internal error"
        finally:
            server.close()

    return _bounded(run)


# Command-line options: (command path, option, the other arguments it needs, values per use).
OPTIONS = [
    (["perform"], "--speed", ["take.mcap", "--port", "p"], 1),
    (["live"], "--count-in", ["--rig", "r.toml", "--port", "p"], 1),
    (["live"], "--sound-offset", ["--rig", "r.toml", "--port", "p"], 1),
    (["record"], "--count-in", ["--rig", "r.toml", "--port", "p", "--out", "t.mcap"], 1),
    (["record"], "--sound-offset", ["--rig", "r.toml", "--port", "p", "--out", "t.mcap"], 1),
    (["keys"], "--sound-offset", ["--rig", "r.toml", "--port", "p", "--out", "s.mcap"], 1),
    (["export"], "--clip", ["take.mcap", "--gltf", "a.glb"], 2),
    (["studio"], "--baud", ["s"], 1),
    (["studio"], "--fps", ["s"], 1),
    (["studio"], "--seconds", ["s"], 1),
    (["studio"], "--size", ["s"], 2),
    (["session", "circle"], "take", ["s", "shot"], 1),
    (["session", "delete"], "take", ["s", "shot"], 1),
    (["session", "lock"], "take", ["s", "shot"], 1),
    (["session", "restore"], "take", ["s", "shot"], 1),
    (["perform"], "--rate", ["take.mcap", "--port", "p"], 1),
    (["perform"], "--watchdog-ms", ["take.mcap", "--port", "p"], 1),
    (["perform"], "--latency-ms", ["take.mcap", "--port", "p"], 1),
    (["perform"], "--baud", ["take.mcap", "--port", "p"], 1),
    (["play"], "--speed", ["take.mcap"], 1),
    (["play"], "--fps", ["take.mcap"], 1),
    (["live"], "--fps", ["--rig", "r.toml", "--port", "p"], 1),
    (["live"], "--seconds", ["--rig", "r.toml", "--port", "p"], 1),
    (["live"], "--watchdog-ms", ["--rig", "r.toml", "--port", "p"], 1),
    (["live"], "--baud", ["--rig", "r.toml", "--port", "p"], 1),
    (["record"], "--rate", ["take.mcap", "--rig", "r.toml", "--port", "p"], 1),
    (["record"], "--seconds", ["take.mcap", "--rig", "r.toml", "--port", "p"], 1),
    (["record"], "--baud", ["take.mcap", "--rig", "r.toml", "--port", "p"], 1),
    (["calibrate"], "--threshold", ["--rig", "r.toml", "--port", "p"], 1),
    (["calibrate"], "--timeout", ["--rig", "r.toml", "--port", "p"], 1),
    (["calibrate"], "--baud", ["--rig", "r.toml", "--port", "p"], 1),
    (["scan"], "--baud", ["--port", "p"], 1),
    (["release"], "--baud", ["--port", "p"], 1),
    (["demo"], "--seconds", [], 1),
    (["demo"], "--fps", [], 1),
    (["demo"], "--size", [], 2),
    (["view"], "--seconds", [], 1),
    (["view"], "--size", [], 2),
    (["batch"], "--size", ["t.mcap", "--out", "o"], 2),
    (["batch"], "--workers", ["t.mcap", "--out", "o"], 1),
    (["rig", "init"], "--skin", ["c.glb"], 1),
    (["rig", "axes"], "--angle", ["r.toml"], 1),
    (["rig", "axes"], "--from", ["r.toml"], 1),
    (["export"], "--keys", ["take.mcap", "--gltf", "a.glb"], 1),
    (["export"], "--keys-units", ["take.mcap", "--gltf", "a.glb", "--keys", "1"], 1),
    (["batch"], "--keys", ["t.mcap", "--out", "o", "--formats", "gltf"], 1),
    (["batch"], "--keys-units", ["t.mcap", "--out", "o", "--formats", "gltf", "--keys", "1"], 1),
    (["batch"], "--retries", ["t.mcap", "--out", "o"], 1),
    (["batch"], "--take-timeout", ["t.mcap", "--out", "o"], 1),
    (["keys"], "--fps", ["--rig", "r.toml", "--port", "p", "--out", "s.mcap"], 1),
    (["keys"], "--step", ["--rig", "r.toml", "--port", "p", "--out", "s.mcap"], 1),
    (["keys"], "--baud", ["--rig", "r.toml", "--port", "p", "--out", "s.mcap"], 1),
    (["keys", "delete"], "index", ["--out", "o.mcap", "s.mcap"], 1),
    (["keys", "goto"], "index", ["--port", "p", "s.mcap"], 1),
    (["keys", "goto"], "--baud", ["s.mcap", "1", "--port", "p"], 1),
    (["keys", "goto"], "--watchdog-ms", ["s.mcap", "1", "--port", "p"], 1),
    (["keys", "goto"], "--latency-ms", ["s.mcap", "1", "--port", "p"], 1),
]
# Options whose value is checked when the command runs (a string until then).
RUN_CHECKED = {("export", "--fps"), ("batch", "--fps"),
               # InRange arguments followed by more arguments (the sweep puts its value last)
               ("note", "take"), ("segment", "take"), ("segment", "in_s"), ("segment", "out_s")}


def option_cases():
    return [(command, option, extra, nargs, label, text) for command, option, extra, nargs in OPTIONS
            for label, text, _ in VALUES]


def option_case(command, option, extra, nargs, text) -> str:
    """Parse the command line as the command does (nothing runs): clean | accepted in range |
    silent wrong (accepted but not finite or outside the option's documented range)."""
    import click

    from puppet.cli import main

    cmd = main
    for name in command:
        cmd = cmd.commands[name]
    positional = not option.startswith("-")  # an argument: its value after "--" (may be "-1")
    args = [*extra, "--", *([text] * nargs)] if positional else [*extra, option, *([text] * nargs)]
    named = f"'{option.upper()}'" if positional else option
    try:
        ctx = cmd.make_context(" ".join(command), args)
    except click.UsageError as err:
        return "clean" if named in err.format_message() else "vague error"
    except Exception:  # noqa: BLE001
        return "internal error"
    param = next(p for p in cmd.params if option in p.opts or option == p.name)
    value = ctx.params[param.name]
    values = value if isinstance(value, tuple) else (value,)
    limits = getattr(param.type, "limits", None) or getattr(getattr(param.type, "types", [None])[0],
                                                             "limits", None)
    if limits is None or not all(limits.holds(v) for v in values):
        return "silent wrong"
    return "correct run"


# hw-sim's numeric options (argparse): the simulator starts (prints its port) or exits 2 with
# one "hw-sim: ..." line naming the option.
HW_SIM_OPTIONS = [("--baud", "baud"), ("--return-delay-us", "return")]


def hw_sim_cases():
    return [(option, word, label, text) for option, word in HW_SIM_OPTIONS
            for label, text, _ in VALUES]


def hw_sim_case(option: str, word: str, text: str) -> str:
    import subprocess

    proc = subprocess.Popen([sys.executable, "-c", "import sys; from hw_sim.cli import main; "
                             "sys.exit(main())", "--servos", "1", option, text],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        started = proc.stdout.readline()  # the port path, or "" when it exits
        if started:
            proc.terminate()
        _, err = proc.communicate(timeout=BOUND_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return "hang"
    if "Traceback" in err:
        return "internal error"
    if started:
        return "correct run"
    lines = [line for line in err.splitlines() if line.startswith("hw-sim: ")]
    return "clean" if proc.returncode == 2 and lines and word in lines[-1] else "vague error"


def table() -> dict[str, collections.Counter]:
    """Outcome counts per source over every case (the report's table)."""
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="fuzz_values_"))
    base = base_rig_text()
    counts = {"rig file": collections.Counter(), "fault file": collections.Counter(),
              "command line": collections.Counter(), "hw-sim options": collections.Counter()}
    for field, how, spec, label, text in rig_cases():
        counts["rig file"][rig_case(folder, base, field, how, spec, label, text)] += 1
    for _, line, word, label, text in fault_cases():
        counts["fault file"][fault_case(folder, line, word, label, text)] += 1
    for command, option, extra, nargs, _, text in option_cases():
        counts["command line"][option_case(command, option, extra, nargs, text)] += 1
    for option, word, _, text in hw_sim_cases():
        counts["hw-sim options"][hw_sim_case(option, word, text)] += 1
    return counts


OK = ("clean", "correct run")


def test_every_rig_field_value_is_refused_by_name_or_solves(tmp_path):
    base = base_rig_text()
    cases = rig_cases()
    assert len(cases) == len(RIG_FIELDS) * len(VALUES)
    outcomes = collections.Counter()
    for field, how, spec, label, text in cases:
        outcome = rig_case(tmp_path, base, field, how, spec, label, text)
        assert outcome in OK, (field, label, outcome)
        outcomes[outcome] += 1
    assert outcomes["correct run"] >= 20  # the in-range draws (0, -0, tiny ...) really solve


def test_pins_on_every_vertex_are_a_clean_error_at_load(tmp_path):
    """They used to reach the solver (MemoryError, or minutes, then an over-determined
    pattern); the count is bounded by the handles when the rig loads."""
    from puppet.rig.errors import RigError
    from puppet.rig.load import PINS_PER_HANDLE, load_rig

    base = re.sub(r"(?ms)^\[\[pin\]\].*?(?=^\[|\Z)", "", base_rig_text())  # its own pin out
    rig = load_rig(_write(tmp_path / "plain.toml", base))
    handles = rig.skeleton.bone_count + rig.solver_options.extra_weights
    n = len(rig.V)
    for count in (PINS_PER_HANDLE * handles + 1, n):
        path = _write(tmp_path / f"pins{count}.toml",
                      base + "".join(f"\n[[pin]]\nvertex = {v}\n" for v in range(count)))
        start = time.monotonic()
        with pytest.raises(RigError) as info:
            load_rig(path)
        assert info.value.field == "pin"
        assert info.value.message.startswith(f"{count} pins; at most {PINS_PER_HANDLE * handles}: ")
        assert time.monotonic() - start < BOUND_S
    pinned = load_rig(_write(tmp_path / "ok.toml", base + "".join(
        f"\n[[pin]]\nvertex = {v}\n" for v in range(0, n, n // 3)[:3])))
    assert len(pinned.pins) == 3


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_every_fault_parameter_value_is_refused_by_name_or_runs(tmp_path):
    cases = fault_cases()
    assert len(cases) >= 9 * len(VALUES)
    for what, line, word, label, text in cases:
        outcome = fault_case(tmp_path, line, word, label, text)
        assert outcome in OK, (what, label, outcome)


def test_every_numeric_option_is_refused_by_name_or_in_its_documented_range():
    for command, option, extra, nargs, label, text in option_cases():
        outcome = option_case(command, option, extra, nargs, text)
        assert outcome in OK, (command, option, label, outcome)


def test_every_hw_sim_numeric_option_is_refused_by_name_or_starts():
    for option, word, label, text in hw_sim_cases():
        outcome = hw_sim_case(option, word, text)
        assert outcome in OK, (option, label, outcome)


def test_every_numeric_option_of_every_command_is_covered():
    """A new numeric option joins OPTIONS (or RUN_CHECKED): none escapes the sweep."""
    import click

    from puppet.cli import main
    from puppet.cli.common import InRange

    covered = {(c[-1], o) for c, o, _, _ in OPTIONS} | RUN_CHECKED
    found = set()

    def walk(cmd):
        if isinstance(cmd, click.Group):
            for sub in cmd.commands.values():
                walk(sub)
        for p in cmd.params:  # a group's own options too (``puppet keys --step``)
            types = getattr(p.type, "types", [p.type])
            if any(isinstance(t, (InRange, click.types._NumberParamTypeBase)) for t in types) or \
                    (p.name == "fps"):
                found.add((cmd.name, p.opts[0]))
            if any(isinstance(t, click.types._NumberParamTypeBase) for t in types):
                raise AssertionError(f"{cmd.name} {p.opts[0]}: a plain click number; use InRange")

    walk(main)
    assert found <= covered, found - covered


def test_threshold_zero_and_negative_are_refused_before_anything_opens():
    from click.testing import CliRunner

    from puppet.cli import main

    for bad in ("0", "-5"):
        result = CliRunner().invoke(main, ["calibrate", "--rig", "none.toml", "--port", "none",
                                           "--guided", "--threshold", bad])
        assert result.exit_code == 2
        assert "Invalid value for '--threshold'" in result.output
        assert "a number 1..90 degrees" in result.output


if __name__ == "__main__":
    start = time.monotonic()
    for source, counter in table().items():
        print(f"{source:14s} " + ", ".join(f"{k}: {v}" for k, v in sorted(counter.items()))
              + f"  (total {sum(counter.values())})")
    print(f"{time.monotonic() - start:.1f} s", file=sys.stderr)
