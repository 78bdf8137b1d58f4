"""Seeded fuzz of takes: cuts, flipped bytes in readings, timestamps and metadata, and the CLI.

Every case ends in one of two acceptable outcomes:
  "clean error": a TakeError naming the file (CLI: exit 1, an ``Error:`` line naming the take,
                 no ``Traceback``);
  "recovered":   every intact reading is returned with its recorded values, nothing else is, the
                 metadata is the recorded one or its damage is reported, and playback ends
                 (CLI: exit 0 and the same BVH as an export of the intact readings alone).
Anything else is classified "traceback", "hang", "silent wrong" or "data loss" and fails.

``python tests/fuzz/test_fuzz_takes.py`` prints the table of outcomes (the issue's case table).
"""

from __future__ import annotations

import struct
import subprocess
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from puppet.reading import Reading
from puppet.take import Playback, TakeError, TakeReader, TakeWriter

SEED = 18
IDS = np.array([3, 7, 11, 12], dtype=np.int64)
MODELS = {3: "XL430-W250", 7: "XL430-W250", 11: "XM430-W350", 12: "XL330-M288"}
RIG_MAP = ('[rig]\nname = "fuzz"\n' + "".join(
    f'[[servo]]\nid = {i}\njoint = "j{i}"\naxis = "x"\n' for i in IDS.tolist()))
CALIBRATION = '{"zero_ticks": {"3": 2048, "7": 1900, "11": -4000, "12": 77}}'
N_READINGS = 60
PERIOD_NS = 2_000_000
T0_NS = 5_000_000_000
FRAME_CAP = 200_000  # frames a playback of a 0.12 s take may take before it counts as a hang
CLI_TIMEOUT_S = 60


def source_readings() -> list[Reading]:
    """The recorded performance: reading i has ticks and ok that are a function of i."""
    out = []
    for i in range(N_READINGS):
        ticks = np.array([i, -3 * i, 4096 * i - 5, (i * 7919) % 100003 - 50000], dtype=np.int32)
        ok = np.array([True, i % 3 != 0, i % 5 != 1, i % 7 != 2])
        out.append(Reading(t_ns=T0_NS + i * PERIOD_NS + (i * 37) % 100, ids=IDS, ticks=ticks,
                           ok=ok))
    return out


def mcap_records(data: bytes) -> list[tuple[int, int, int]]:
    """(opcode, start, end) of every record of a well-formed, unchunked MCAP file."""
    pos, out = 8, []
    while pos + 9 <= len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        out.append((opcode, pos, pos + 9 + length))
        pos += 9 + length
    return out


@dataclass
class Take:
    """A clean take's bytes and where its parts lie."""

    data: bytes
    readings: list  # source Readings, in order
    messages: list  # (start, end) of reading i's record
    header_end: int  # first byte of the first reading's record
    data_end: int  # end of the last reading's record


def make_take(path: Path, readings, *, ids=IDS, models=MODELS, rig_map=RIG_MAP,
              calibration=CALIBRATION, rig_name="fuzz") -> Take:
    with TakeWriter(path, ids=ids, models=models, rig_map_text=rig_map,
                    calibration_text=calibration, rig_name=rig_name) as w:
        for r in readings:
            w.write(r)
    data = path.read_bytes()
    messages = [(s, e) for op, s, e in mcap_records(data) if op == 0x05]
    assert len(messages) == len(readings)
    return Take(data, list(readings), messages, messages[0][0], messages[-1][1])


@dataclass
class Case:
    """One damaged take: its bytes and the indices of the readings left intact."""

    name: str
    data: bytes
    intact: list[int]
    damaged_meta: bool = False


def flip(data: bytes, offsets, rng) -> bytes:
    out = bytearray(data)
    for off in offsets:
        out[off] ^= int(rng.integers(1, 256))
    return bytes(out)


def library_cases(take: Take) -> list[Case]:
    """The seeded cases against the library (TakeReader + Playback)."""
    rng = np.random.default_rng(SEED)
    n = len(take.readings)
    cases = []
    for c in range(25):  # cuts at random offsets
        cut = int(rng.integers(0, len(take.data)))
        intact = [i for i, (_, e) in enumerate(take.messages) if e <= cut]
        cases.append(Case(f"cut-{c}@{cut}", take.data[:cut], intact))
    for c in range(40):  # one flipped byte anywhere in one reading's record
        j = int(rng.integers(0, n))
        s, e = take.messages[j]
        off = int(rng.integers(s, e))
        cases.append(Case(f"flip-reading-{c}:r{j}+{off - s}", flip(take.data, [off], rng),
                          [i for i in range(n) if i != j]))
    for c in range(12):  # one flipped byte in one reading's own timestamp (payload t_ns)
        j = int(rng.integers(0, n))
        s, e = take.messages[j]
        off = s + 9 + 22 + 4 + int(rng.integers(0, 8))
        cases.append(Case(f"flip-t_ns-{c}:r{j}+{off - s}", flip(take.data, [off], rng),
                          [i for i in range(n) if i != j]))
    for c in range(6):  # one flipped byte in one reading's MCAP log time
        j = int(rng.integers(0, n))
        s, e = take.messages[j]
        off = s + 9 + 6 + int(rng.integers(0, 8))
        cases.append(Case(f"flip-logtime-{c}:r{j}+{off - s}", flip(take.data, [off], rng),
                          [i for i in range(n) if i != j]))
    for c in range(6):  # three flipped readings
        js = sorted(int(j) for j in rng.choice(n, size=3, replace=False))
        offs = [int(rng.integers(*take.messages[j])) for j in js]
        cases.append(Case(f"flip-3-readings-{c}:r{js}", flip(take.data, offs, rng),
                          [i for i in range(n) if i not in js]))
    for c in range(30):  # one flipped byte in the header records (metadata, schema, channel)
        off = int(rng.integers(8, take.header_end))
        cases.append(Case(f"flip-metadata-{c}@{off}", flip(take.data, [off], rng),
                          list(range(n)), damaged_meta=True))
    for c in range(6):  # one flipped byte after the readings (data end, summary, footer)
        off = int(rng.integers(take.data_end, len(take.data)))
        cases.append(Case(f"flip-summary-{c}@{off}", flip(take.data, [off], rng), list(range(n))))
    return cases


def same_reading(a, b) -> bool:
    return (a.t_ns == b.t_ns and a.ticks.tolist() == b.ticks.tolist()
            and a.ok.tolist() == b.ok.tolist())


def classify_library(case: Case, take: Take, path: Path) -> tuple[str, str]:
    """(outcome, detail) of reading and playing one damaged take in this process."""
    path.write_bytes(case.data)
    try:
        reader = TakeReader(path)
        got = list(reader.readings())
        arrays = reader.arrays()
        frames = 0
        for _ in (Playback.of_take(reader, reader.metadata.ids, fps=60) if len(reader) else ()):
            frames += 1
            if frames > FRAME_CAP:
                return "hang", f"playback passed {FRAME_CAP} frames"
    except TakeError as e:
        if str(path) in str(e):
            return "clean error", str(e)
        return "traceback", f"TakeError without the path: {e}"
    except Exception as e:  # noqa: BLE001 - the fuzz classifies whatever escapes
        return "traceback", f"{type(e).__name__}: {e}"
    source = take.readings
    # Every returned reading must be a source reading, in recorded order.
    k = 0
    for g in got:
        while k < len(source) and not same_reading(g, source[k]):
            k += 1
        if k == len(source):
            return "silent wrong", f"returned a reading not in the source: t_ns={g.t_ns}"
        k += 1
    t, ticks, ok = arrays
    if (t.tolist() != [g.t_ns for g in got]
            or ticks.tolist() != [g.ticks.tolist() for g in got]
            or ok.tolist() != [g.ok.tolist() for g in got]):
        return "silent wrong", "arrays() disagrees with readings()"
    returned = {g.t_ns for g in got}
    lost = [i for i in case.intact if source[i].t_ns not in returned]
    if case.damaged_meta and reader.recovery is None:
        meta = reader.metadata
        if (meta.rig_map_text != RIG_MAP or meta.calibration_text != CALIBRATION
                or meta.ids.tolist() != IDS.tolist() or meta.models != MODELS
                or meta.rig_name != "fuzz"):
            return "silent wrong", "metadata changed and nothing reported"
    if lost:
        return "data loss", f"intact readings {lost[:5]}... of {len(case.intact)} not returned"
    return "recovered", f"{len(got)} readings" + (f"; {reader.recovery}" if reader.recovery else "")


# ---- the command line: export of a damaged take of the built-in rig ----

def critter_take(path: Path) -> Take:
    from puppet.rig import builtin

    rig = builtin()
    k = len(rig.servo_map)
    ids = np.asarray(rig.servo_map.ids)
    readings = []
    for i in range(24):
        ticks = (rig.servo_map.zero + 400 * np.sin(0.3 * i + np.arange(k))).astype(np.int32)
        readings.append(Reading(T0_NS + i * 25_000_000, ids, ticks, np.ones(k, bool)))
    calibration = '{"zero_ticks": {%s}}' % ", ".join(
        f'"{int(i)}": {int(z)}' for i, z in zip(rig.servo_map.ids, rig.servo_map.zero))
    return make_take(path, readings, ids=[int(i) for i in ids], models=dict(rig.servo_map.models),
                     rig_map="", calibration=calibration, rig_name=rig.name)


def cli_cases(take: Take) -> list[Case]:
    rng = np.random.default_rng(SEED + 1)
    n = len(take.readings)
    mid = take.messages[n // 2]
    cut = int(rng.integers(*take.messages[n - 5]))
    t_high = mid[0] + 9 + 22 + 4 + 6  # a high byte of reading n/2's t_ns: hours away
    length = take.messages[5][0] + 2  # a byte of reading 5's record length
    calib = take.data.find(b"zero_ticks")
    return [
        Case("cli-cut", take.data[:cut], list(range(n - 5))),
        Case("cli-flip-ticks", flip(take.data, [mid[0] + 9 + 22 + 16 + 3], rng),
             [i for i in range(n) if i != n // 2]),
        Case("cli-flip-t_ns", flip(take.data, [t_high], rng), [i for i in range(n) if i != n // 2]),
        Case("cli-flip-length", flip(take.data, [length], rng), [i for i in range(n) if i != 5]),
        Case("cli-flip-calibration", flip(take.data, [calib + 20], rng), list(range(n)),
             damaged_meta=True),
    ]


def export_bvh(take_path: Path, bvh: Path):
    puppet = Path(sys.executable).with_name("puppet")
    return subprocess.run([str(puppet), "export", str(take_path), "--bvh", str(bvh), "--fps", "20"],
                          capture_output=True, text=True, timeout=CLI_TIMEOUT_S)


def classify_cli(case: Case, take: Take, folder: Path) -> tuple[str, str]:
    path = folder / f"{case.name}.mcap"
    path.write_bytes(case.data)
    bvh = folder / f"{case.name}.bvh"
    try:
        result = export_bvh(path, bvh)
    except subprocess.TimeoutExpired:
        return "hang", f"export ran past {CLI_TIMEOUT_S} s"
    err = result.stderr
    if "Traceback" in err or "internal error" in err or result.returncode not in (0, 1):
        return "traceback", err.strip().splitlines()[-1] if err.strip() else f"rc {result.returncode}"
    if result.returncode == 1:
        if "Error:" in err and str(path) in err:
            return "clean error", err.strip().splitlines()[-1]
        return "traceback", f"exit 1 without an Error line naming the take: {err!r}"
    # Exit 0: the export must equal an export of the intact readings alone.
    ref_take = folder / f"{case.name}.ref.mcap"
    critter_reference(ref_take, [take.readings[i] for i in case.intact])
    ref = folder / f"{case.name}.ref.bvh"
    ref_result = export_bvh(ref_take, ref)
    assert ref_result.returncode == 0, ref_result.stderr
    if bvh.read_text() != ref.read_text():
        lines, ref_lines = len(bvh.read_text().splitlines()), len(ref.read_text().splitlines())
        kind = "data loss" if lines < ref_lines else "silent wrong"
        return kind, f"BVH of {lines} lines, the intact readings give {ref_lines}"
    warning = [line for line in err.splitlines() if line.startswith(f"warning: {path}: ")]
    if not warning:
        return "silent wrong", "the damage was not reported"
    return "recovered", warning[0]


def critter_reference(path: Path, readings) -> None:
    from puppet.rig import builtin

    rig = builtin()
    calibration = '{"zero_ticks": {%s}}' % ", ".join(
        f'"{int(i)}": {int(z)}' for i, z in zip(rig.servo_map.ids, rig.servo_map.zero))
    make_take(path, readings, ids=[int(i) for i in rig.servo_map.ids],
              models=dict(rig.servo_map.models), rig_map="", calibration=calibration,
              rig_name=rig.name)


# ---- pytest ----

@pytest.fixture(scope="module")
def clean_take(tmp_path_factory) -> Take:
    return make_take(tmp_path_factory.mktemp("fuzz") / "clean.mcap", source_readings())


def test_fuzz_library_cases(clean_take, tmp_path):
    outcomes = []
    for case in library_cases(clean_take):
        outcome, detail = classify_library(case, clean_take, tmp_path / "case.mcap")
        outcomes.append((case.name, outcome, detail))
    bad = [o for o in outcomes if o[1] not in ("clean error", "recovered")]
    assert bad == []
    counts = Counter(o[1] for o in outcomes)
    assert counts["recovered"] > counts["clean error"]  # most damage is recovered, not refused


def test_fuzz_cli_export(tmp_path):
    take = critter_take(tmp_path / "critter.mcap")
    outcomes = []
    for case in cli_cases(take):
        outcome, detail = classify_cli(case, take, tmp_path)
        outcomes.append((case.name, outcome, detail))
    bad = [o for o in outcomes if o[1] not in ("clean error", "recovered")]
    assert bad == []


def main() -> None:
    """Print the case table (outcome counts, then every case that did not end acceptably)."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        take = make_take(folder / "clean.mcap", source_readings())
        rows = [(c.name, *classify_library(c, take, folder / "case.mcap"))
                for c in library_cases(take)]
        if "--no-cli" not in sys.argv:
            ctake = critter_take(folder / "critter.mcap")
            rows += [(c.name, *classify_cli(c, ctake, folder)) for c in cli_cases(ctake)]
    kinds = ["clean error", "recovered", "traceback", "hang", "silent wrong", "data loss"]
    counts = Counter(r[1] for r in rows)
    print(f"cases: {len(rows)}  " + "  ".join(f"{k}: {counts[k]}" for k in kinds))
    groups = sorted({r[0].split(":")[0].split("@")[0].rstrip("0123456789-") for r in rows})
    for g in groups:
        sub = [r for r in rows if r[0].split(":")[0].split("@")[0].rstrip("0123456789-") == g]
        c = Counter(r[1] for r in sub)
        print(f"  {g:22s} {len(sub):3d}  " + "  ".join(f"{k}: {c[k]}" for k in kinds if c[k]))
    for name, outcome, detail in rows:
        if outcome not in ("clean error", "recovered") or "-v" in sys.argv:
            print(f"{outcome:12s} {name}: {detail[:160]}")


if __name__ == "__main__":
    main()
