"""``rig init`` on generated glTF characters with hostile names, counts, transforms and
accessors (seeded, deterministic).

Each case starts from the skinned test character (tests/rig/character.py), changes one thing,
and runs ``puppet rig init`` then ``puppet rig info`` on what it wrote. Every case must end,
within a generous time bound, in a clean error naming the .glb (exit 1, one ``Error:`` line,
no traceback) or in a rig file that loads.

``python tests/fuzz/test_fuzz_gltf.py`` prints the case table (outcomes); run it with another
checkout's interpreter for a before/after comparison.
"""

from __future__ import annotations

import collections
import importlib.util
import random
import signal
import struct
import sys
import time
from pathlib import Path

import numpy as np
import pygltflib as g

SEED = 26
BOUND_S = 120.0  # per case: generous on a loaded 2-core machine; a hang is far beyond it


def _character():
    spec = importlib.util.spec_from_file_location(
        "fuzz_gltf_character", Path(__file__).parents[1] / "rig" / "character.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


character = _character()
NAMES = ["\x01ctrl", "del\x7f", "new\nline", 'a "quoted" name', "back\\slash", "sep\u2028arator",
         "lone \ud800 surrogate", "", "   ", "x" * 300, "ü漢字 ok", "# [[servo]]", "tab\there",
         "nul\x00", "zero\u200dwidth", "\U0001F600 emoji", "bad\udfff"]


def joint_nodes(doc) -> list[int]:
    return list(doc.skins[0].joints)


def add_chain(doc, count: int) -> None:
    """``count`` more joints, each the child of the last, below the last joint (identity IBMs)."""
    parent = joint_nodes(doc)[-1]
    for k in range(count):
        doc.nodes.append(g.Node(name=f"chain{k}", translation=[0.0, 0.01, 0.0], children=[]))
        doc.nodes[parent].children.append(len(doc.nodes) - 1)
        doc.skins[0].joints.append(len(doc.nodes) - 1)
        parent = len(doc.nodes) - 1
    doc.skins[0].inverseBindMatrices = None


def cases() -> list[tuple[str, callable]]:
    """[(name, mutate(doc, rng))]: one change each."""
    out = []
    for i, name in enumerate(NAMES):
        def rename(doc, rng, name=name):
            doc.nodes[rng.choice(joint_nodes(doc))].name = name
        out.append((f"name {ascii(name)[:24]}", rename))

    def every_name_same(doc, rng):
        for j in joint_nodes(doc):
            doc.nodes[j].name = "same"
    out.append(("every joint named alike", every_name_same))
    for count in (1, 60, 1200, 2100):
        out.append((f"chain of {count} more joints", lambda doc, rng, c=count: add_chain(doc, c)))

    def no_joints(doc, rng):
        doc.skins[0].joints = []
    out.append(("skin with no joints", no_joints))
    for label, field, value in [
            ("translation inf", "translation", [float("inf"), 0.0, 0.0]),
            ("translation nan", "translation", [0.0, float("nan"), 0.0]),
            ("translation 1e308", "translation", [1e308, 0.0, 0.0]),
            ("translation 1e200 (overflows down the chain)", "translation", [1e200, 1e200, 1e200]),
            ("scale 0", "scale", [0.0, 0.0, 0.0]),
            ("scale 1e300", "scale", [1e300, 1e300, 1e300]),
            ("scale -1", "scale", [-1.0, 1.0, 1.0]),
            ("rotation zero", "rotation", [0.0, 0.0, 0.0, 0.0]),
            ("rotation nan", "rotation", [float("nan"), 0.0, 0.0, 1.0]),
            ("matrix nan", "matrix", [float("nan")] * 16),
            ("matrix zeros", "matrix", [0.0] * 16)]:
        def transform(doc, rng, field=field, value=value):
            for j in joint_nodes(doc)[:2]:  # the root joint and its child
                setattr(doc.nodes[j], field, list(value))
        out.append((label, transform))

    def armature_inf(doc, rng):
        doc.nodes[0].translation = [float("-inf"), 0.0, 0.0]
    out.append(("armature (non-joint parent) at -inf", armature_inf))

    def cycle(doc, rng):
        first = joint_nodes(doc)[0]
        doc.nodes[joint_nodes(doc)[-1]].children.append(first)
    out.append(("node hierarchy cycle", cycle))

    def prims(doc):
        return [p for m in doc.meshes for p in m.primitives]

    def no_indices(doc, rng):
        for p in prims(doc):
            doc.accessors[p.indices].count = 0
    out.append(("no triangles (empty indices)", no_indices))

    def no_positions(doc, rng):
        for p in prims(doc):
            for a in (p.attributes.POSITION, p.attributes.JOINTS_0, p.attributes.WEIGHTS_0):
                doc.accessors[a].count = 0
            p.indices = None
    out.append(("no vertices", no_positions))

    def two_indices(doc, rng):
        for p in prims(doc):
            doc.accessors[p.indices].count = 2
    out.append(("indices not triples", two_indices))

    def lines_mode(doc, rng):
        prims(doc)[0].mode = 1
    out.append(("primitive of lines", lines_mode))

    def huge_count(doc, rng):
        doc.accessors[prims(doc)[0].attributes.POSITION].count = 2**31 - 1
    out.append(("POSITION count 2^31-1", huge_count))

    def bad_view(doc, rng):
        doc.accessors[prims(doc)[0].attributes.POSITION].bufferView = 999
    out.append(("POSITION bufferView missing", bad_view))

    def bad_component(doc, rng):
        doc.accessors[prims(doc)[0].attributes.WEIGHTS_0].componentType = 9999
    out.append(("WEIGHTS componentType unknown", bad_component))

    def bad_type(doc, rng):
        doc.accessors[prims(doc)[0].attributes.POSITION].type = "VEC2"
    out.append(("POSITION as VEC2", bad_type))

    def joints_out_of_range(doc, rng):
        doc.skins[0].joints = doc.skins[0].joints[:2]
        doc.skins[0].inverseBindMatrices = None
    out.append(("JOINTS index past the skin", joints_out_of_range))

    def small_stride(doc, rng):
        view = doc.accessors[prims(doc)[0].attributes.POSITION].bufferView
        doc.bufferViews[view].byteStride = 4
    out.append(("byteStride below one element", small_stride))
    return out


def save_glb(doc, blob: bytes, path: Path) -> None:
    """A .glb of doc and blob; unlike pygltflib's writer, non-finite numbers are written (as
    JSON's Infinity / NaN, which JSON readers, pygltflib's included, accept)."""
    doc.buffers[0].byteLength = len(blob)
    text = doc.to_json(default=g.json_serial, allow_nan=True, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    blob = blob + b"\0" * (-len(blob) % 4)
    body = (struct.pack("<II", len(text), 0x4E4F534A) + text
            + struct.pack("<II", len(blob), 0x004E4942) + blob)
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)


def write_case(folder: Path, index: int, mutate, rng) -> Path:
    doc, blob = character.build()
    mutate(doc, rng)
    path = folder / f"case{index:02d}.glb"
    save_glb(doc, blob, path)
    return path


class _Overtime(Exception):
    pass


def run_case(path: Path) -> str:
    """rig init, then rig info on its rig file, in-process through the command line:
    clean | loads | traceback | vague error | unloadable | hang."""
    from click.testing import CliRunner

    from puppet.cli import main

    def alarm(_signum, _frame):
        raise _Overtime

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, BOUND_S)
    try:
        rig = path.with_suffix(".toml")
        rig.unlink(missing_ok=True)
        runner = CliRunner()
        result = runner.invoke(main, ["rig", "init", str(path)])
        if isinstance(result.exception, _Overtime):
            return "hang"
        if result.exception is not None and not isinstance(result.exception, SystemExit):
            return "traceback"
        if "internal error" in result.output or "Traceback" in result.output:
            return "traceback"
        if result.exit_code != 0:
            errors = [line for line in result.output.splitlines() if line.startswith("Error: ")]
            return "clean" if len(errors) == 1 and str(path) in errors[0] else "vague error"
        info = runner.invoke(main, ["rig", "info", str(rig)])
        if isinstance(info.exception, _Overtime):
            return "hang"
        return "loads" if info.exit_code == 0 else "unloadable"
    except _Overtime:
        return "hang"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def outcomes(folder: Path) -> list[tuple[str, str]]:
    rng = random.Random(SEED)
    return [(name, run_case(write_case(folder, i, mutate, rng)))
            for i, (name, mutate) in enumerate(cases())]


def test_every_generated_gltf_is_a_clean_error_or_a_rig_that_loads(tmp_path):
    found = outcomes(tmp_path)
    assert len(found) >= 40
    bad = [(name, outcome) for name, outcome in found if outcome not in ("clean", "loads")]
    assert bad == []
    by_name = dict(found)
    # What each kind of case must give (not merely "no crash").
    assert by_name["chain of 1200 more joints"] == "loads"
    assert by_name["chain of 2100 more joints"] == "clean"
    assert by_name["name 'del\\x7f'"] == "loads"
    assert by_name["name 'lone \\ud800 surrogate'"] == "clean"
    assert by_name["no triangles (empty indices)"] == "clean"
    assert by_name["translation inf"] == "clean"
    assert by_name["translation 1e200 (overflows down the chain)"] == "clean"


def test_escaped_names_read_back_exactly(tmp_path):
    """A name with control characters is written escaped and the rig file loads it unchanged."""
    from puppet.rig.init_file import write_rig_init
    from puppet.rig.load import load_rig

    doc, blob = character.build()
    names = ["del\x7f", "new\nline", 'q"uote\\', "sep\u2028x", "zero\u200dwidth"]
    for node, name in zip(joint_nodes(doc)[1:], names):
        doc.nodes[node].name = name
    glb = tmp_path / "odd.glb"
    save_glb(doc, blob, glb)
    rig_path, _ = write_rig_init(glb)
    text = rig_path.read_text(encoding="utf-8")
    assert "\x7f" not in text and "\u2028" not in text
    rig = load_rig(rig_path)
    assert set(names) <= set(rig.skeleton.names)


if __name__ == "__main__":
    import tempfile

    start = time.monotonic()
    found = outcomes(Path(tempfile.mkdtemp(prefix="fuzz_gltf_")))
    for name, outcome in found:
        print(f"{outcome:12s} {name}")
    print(dict(collections.Counter(outcome for _, outcome in found)))
    print(f"{time.monotonic() - start:.1f} s", file=sys.stderr)
