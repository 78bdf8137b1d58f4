"""Broken hw_sim fault files, as a user might write them (seeded, deterministic).

Each one given to ``puppet demo --faults`` ends in a clean error before anything starts: exit 1,
one ``Error: FILE:LINE: …`` line on stderr, no traceback. A valid file written around the bad
line puts the fault on a known line, so the line number is checked too.
"""

from __future__ import annotations

import random
import subprocess
import sys

import pytest

from hw_sim.faults import FaultSchedule

SEED = 18
GOOD_LINES = ["# a comment", "0.5 drop ids=3 for=0.2", "", "1.0 power_cycle ids=2 for=0.3",
              "2.0 noise ids=1-4,7 amplitude=3"]

# Each case: a bad fault line (the words the error must contain follow it).
BAD_LINES = [
    ("0.5 drop ids=3 for=nan", "duration"),                     # never ends today
    ("0.5 drop ids=3 for=inf", "duration"),
    ("0.5 drop ids=3 for=1e999", "duration"),
    ("0.5 drop ids=3 for=-1", "duration"),
    ("nan drop ids=3", "start time"),
    ("inf unplug", "start time"),
    ("-0.5 drop ids=3", "start time"),
    ("1e300 drop ids=3", "start time"),
    ("0.5 hardware_error ids=3 bits=-1", "bits"),               # kills the simulator today
    ("0.5 hardware_error ids=3 bits=256", "bits"),
    ("0.5 hardware_error ids=3 bits=nan", "bits"),
    ("0.5 hardware_error ids=3 error=melting", "error"),
    ("0.5 error_status ids=3 error=300", "error"),
    ("0.5 error_status ids=3 error=-2", "error"),
    ("0.5 drop ids=3 p=nan", "p="),
    ("0.5 drop ids=3 p=1.5", "p="),
    ("0.5 drop ids=3 p=-0.1", "p="),
    ("0.5 bad_crc ids=3 p=inf", "p="),
    ("0.5 truncate ids=3 keep=-3", "keep"),
    ("0.5 truncate ids=3 keep=1.5", "keep"),
    ("0.5 noise ids=3 amplitude=-4", "amplitude"),
    ("0.5 noise ids=3 amplitude=1e9", "amplitude"),
    ("0.5 duplicate_id ids=2 offset=99999999999", "offset"),
    ("0.5 drop ids=1-99999999", "ids"),                          # would build a huge list
    ("0.5 drop ids=300", "ids"),
    ("0.5 drop ids=-3", "ids"),
    ("0.5 drop ids=5-2", "ids"),
    ("0.5 drop ids=,", "ids"),
    ("0.5 melt ids=3", "melt"),
    ("0.5 drop ids=3 colour=red", "colour"),
    ("0.5 drop ids=3 for", "for"),
    ("0.5 drop ids=3 for=", "for"),
    ("soon drop ids=3", "start time"),
    ("0.5", "expected"),
]


def _broken_files(tmp_path):
    """Each bad line placed at a random line among good ones: (path, line number, words)."""
    rng = random.Random(SEED)
    files = []
    for n, (bad, word) in enumerate(BAD_LINES):
        lines = rng.sample(GOOD_LINES, rng.randint(0, len(GOOD_LINES)))
        at = rng.randint(0, len(lines))
        lines.insert(at, bad)
        path = tmp_path / f"faults_{n:02d}.txt"
        path.write_text("\n".join(lines) + "\n")
        files.append((path, at + 1, word))
    return files


def _undecodable(tmp_path):
    path = tmp_path / "latin1.txt"
    path.write_bytes("0.5 drop ids=3\n# caf\xe9\n".encode("latin-1"))
    return path, 2, "UTF-8"


def test_every_broken_fault_file_is_a_clean_error(tmp_path):
    cases = _broken_files(tmp_path) + [_undecodable(tmp_path)]
    assert len(cases) >= 20
    # One interpreter for all the cases: each runs the real command line in-process, as
    # ``puppet demo --faults FILE`` does; the stderr of each is checked below.
    script = (
        "import sys\n"
        "from click.testing import CliRunner\n"
        "from puppet.cli import main\n"
        "runner = CliRunner()\n"
        "for path in sys.argv[1:]:\n"
        "    r = runner.invoke(main, ['demo', '--faults', path, '--seconds', '1', '--out', path + '.mp4'])\n"
        "    tb = r.exc_info is not None and r.exception is not None and not isinstance(r.exception, SystemExit)\n"
        "    print(repr((path, r.exit_code, tb, r.output)))\n"
    )
    result = subprocess.run([sys.executable, "-c", script, *(str(p) for p, _, _ in cases)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    outcomes = [eval(line) for line in result.stdout.splitlines()]  # noqa: S307 - our own reprs
    assert [o[0] for o in outcomes] == [str(p) for p, _, _ in cases]
    for (path, line, word), (_, code, traceback, output) in zip(cases, outcomes):
        assert code == 1, (path.read_text(errors="replace"), output)
        assert not traceback and "Traceback" not in output, output
        errors = [text for text in output.splitlines() if text.startswith("Error: ")]
        assert len(errors) == 1, output
        assert errors[0].startswith(f"Error: {path}:{line}: "), (errors[0], line)
        assert word in errors[0], (word, errors[0])
        assert not (tmp_path / (path.name + ".mp4")).exists()   # nothing started


def test_broken_fault_file_through_the_real_command(tmp_path):
    """The same, as a user runs it: a subprocess, stderr, exit status."""
    path = tmp_path / "faults.txt"
    path.write_text("0.5 drop ids=3 for=0.2\n1.0 hardware_error ids=3 bits=-1\n")
    result = subprocess.run(["puppet", "demo", "--faults", str(path), "--out", str(tmp_path / "d.mp4")],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines() == [
        f"Error: {path}:2: fault 'hardware_error': bits=-1 is not in 0..255"]
    simulator = subprocess.run(["hw-sim", "--faults", str(path)], capture_output=True, text=True, timeout=60)
    assert simulator.returncode == 2
    assert "Traceback" not in simulator.stderr
    assert f"{path}:2: fault 'hardware_error': bits=-1" in simulator.stderr


@pytest.mark.parametrize("line", [
    "0.5 drop ids=3 for=0.2", "0 unplug for=0.5s", "3.0 hardware_error ids=4 error=overload",
    "1 hardware_error ids=1 bits=0x24", "4.0 noise ids=1-4,7 amplitude=3", "0.1 truncate keep=0",
    "0.2 duplicate_id ids=2 offset=-100", "0.3 error_status ids=1 error=7 p=0.5", "0 echo",
])
def test_valid_lines_still_parse(tmp_path, line):
    path = tmp_path / "ok.txt"
    path.write_text(line + "\n")
    assert len(FaultSchedule.from_file(path)) == 1


def test_seeded_mutations_parse_or_fail_cleanly(tmp_path):
    """Numbers and words of valid lines replaced at random: every file either parses into
    faults whose numbers are all finite, or fails with a FaultFileError naming file and line."""
    import math

    from hw_sim.errors import FaultFileError

    rng = random.Random(SEED)
    valid = ["0.5 drop ids=3 for=0.2 p=0.5", "1.0 power_cycle ids=2 for=0.3", "2 unplug for=0.5",
             "3.0 hardware_error ids=4 bits=0x20", "4.0 noise ids=1-4,7 amplitude=3",
             "0.1 truncate ids=2 keep=4", "0.2 duplicate_id ids=2 offset=100", "0.3 error_status error=7"]
    junk = ["nan", "inf", "-inf", "-1", "1e999", "0x", "", "=", "9" * 40, "1-", "ids", "0.5s", "\t"]
    failed = 0
    for n in range(200):
        words = rng.choice(valid).split()
        k = rng.randrange(len(words))
        key, eq, _ = words[k].partition("=")
        words[k] = f"{key}={rng.choice(junk)}" if eq else rng.choice(junk)
        lines = rng.sample(valid, 2)
        at = rng.randint(0, 2)
        lines.insert(at, " ".join(words))
        path = tmp_path / f"m{n:03d}.txt"
        path.write_text("\n".join(lines) + "\n")
        try:
            schedule = FaultSchedule.from_file(path)
        except FaultFileError as err:
            failed += 1
            assert str(err).startswith(f"{path}:{at + 1}: "), str(err)
            continue
        for fault in schedule.faults:
            numbers = [fault.start_s, fault.duration_s or 0.0]
            numbers += [v for v in fault.params.values() if isinstance(v, (int, float))]
            assert all(math.isfinite(v) for v in numbers), fault
    assert failed >= 100   # most mutations break the line
