"""--mute, --solo and --punch on export, play and batch of a layered take: the flags reach the
one take-to-frames rule (Playback.of_take's LayerOptions) through take_frames, and bad flags
are refused naming the flag."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from puppet.batch import run_batch
from puppet.cli import main
from puppet.rig import load_rig
from puppet.rig.load import BUILTIN_RIG
from puppet.take import TakeReader
from puppet.take.layers import LayerOptions, LayerRef, compose
from tests.layers.test_compose import _write

FPS = 10
SECONDS = 6.0
SOLVE_DEG = 1.0
"""How far (degrees) a free bone's solve may differ after a seam (it starts from the frame
before)."""


@pytest.fixture(scope="module")
def rig():
    return load_rig(BUILTIN_RIG)


@pytest.fixture
def stack(tmp_path, rig):
    """(base, layer over it holding servos 1-3, a plain take elsewhere) paths."""
    base = _write(tmp_path / "base.mcap", rig, SECONDS, 0.0, start_ns=1_000_000_000)
    layer = tmp_path / "layer.mcap"
    _write(layer, rig, SECONDS, 1.0, start_ns=7_000_000_000, raw_other=100,
           layer=LayerRef.over(base, layer, [1, 2, 3], rig_name=rig.name))
    other = _write(tmp_path / "other.mcap", rig, 2.0, 2.0, start_ns=1_000_000_000)
    return base, layer, other


def _export(take, out, *flags):
    result = CliRunner().invoke(main, ["export", str(take), "--rig", str(BUILTIN_RIG), "--bvh",
                                       str(out), "--fps", str(FPS), *map(str, flags)])
    return result


def _motion(path) -> np.ndarray:
    """(frames, channels) of a BVH file's MOTION section."""
    lines = path.read_text().split("MOTION", 1)[1].splitlines()
    rows = [line for line in lines if line and line[0] in "-0123456789"]
    return np.array([[float(v) for v in row.split()] for row in rows])


def test_mute_solo_and_punch_reach_the_export(tmp_path, stack, rig):
    base, layer, _ = stack
    runs = {}
    for name, flags in {"base": (), "layer": (), "muted": ("--mute", layer),
                        "solo": ("--solo", layer),
                        "punched": ("--punch", f"{layer}=1:5")}.items():
        out = tmp_path / f"{name}.bvh"
        result = _export(base if name == "base" else layer, out, *flags)
        assert result.exit_code == 0, result.output
        runs[name] = _motion(out)
    assert runs["layer"].shape == runs["base"].shape
    assert np.abs(runs["layer"] - runs["base"]).max() > 1.0  # the layer holds its servos
    np.testing.assert_array_equal(runs["muted"], runs["base"])  # muted: the base plays through
    np.testing.assert_array_equal(runs["solo"], runs["layer"])  # the only layer: as recorded
    t = np.arange(len(runs["base"])) / FPS
    with TakeReader(layer) as reader:  # the seams' blends, as the rule sized them
        (_, blend_in), (_, blend_out) = compose(
            reader, rig.servo_map.ids, LayerOptions(punch={str(layer): ("1", "5")})).seams
    before, inside, after = t < 1.0, (t > 1 + blend_in) & (t < 5 - blend_out), t > 5.0
    assert inside.sum() > 3 and after.sum() > 3
    np.testing.assert_array_equal(runs["punched"][before], runs["base"][before])
    # the free bones' solve starts from the frame before: within a fraction of a degree of each
    # pass once the seam is behind, where the passes differ by far more
    assert np.abs(runs["layer"][inside] - runs["base"][inside]).max() > 10 * SOLVE_DEG
    assert np.abs(runs["layer"][after] - runs["base"][after]).max() > 10 * SOLVE_DEG
    np.testing.assert_allclose(runs["punched"][inside], runs["layer"][inside], atol=SOLVE_DEG)
    np.testing.assert_allclose(runs["punched"][after], runs["base"][after], atol=SOLVE_DEG)


def test_a_punch_at_markers_names_them(tmp_path, stack):
    _, layer, _ = stack
    result = _export(layer, tmp_path / "a.bvh", "--punch", f"{layer}=start:1")
    assert result.exit_code == 1
    assert "punch in 'start' is neither seconds nor one of its markers" in result.output


@pytest.mark.parametrize("flags, said", [
    (("--punch", "layer.mcap"), "--punch: 'layer.mcap' is not LAYER=IN:OUT"),
    (("--punch", "{layer}=1"), "is not LAYER=IN:OUT"),
    (("--mute", "{dir}/missing.mcap"), "missing.mcap: --mute: no such layer take"),
    (("--solo", "{other}"), "--solo {other}: not a layer of this take's stack"),
    (("--punch", "{layer}=2:1"), "punch out (1.000 s) is not after punch in (2.000 s)"),
])
def test_bad_layer_flags_are_refused_naming_the_flag(tmp_path, stack, flags, said):
    _, layer, other = stack
    fill = {"layer": layer, "other": other, "dir": tmp_path}
    flags = [f.format(**fill) for f in flags]
    out = tmp_path / "x.bvh"
    result = _export(layer, out, *flags)
    assert result.exit_code == 1, result.output
    assert "Error:" in result.output and said.format(**fill) in result.output
    assert "Traceback" not in result.output
    assert not out.exists()


def test_a_plain_take_refuses_a_layer_flag(tmp_path, stack):
    base, layer, _ = stack
    result = _export(base, tmp_path / "x.bvh", "--mute", layer)
    assert result.exit_code == 1
    assert "not a layer of this take's stack (its layers: none" in result.output


def test_play_mutes_a_layer(tmp_path, stack):
    base, layer, _ = stack
    frames = {}
    for name, take, flags in (("base", base, ()), ("muted", layer, ("--mute", layer)),
                              ("layer", layer, ())):
        folder = tmp_path / name
        result = CliRunner().invoke(main, ["play", str(take), "--rig", str(BUILTIN_RIG),
                                           "--frames", str(folder), "--fps", "2",
                                           *map(str, flags)])
        assert result.exit_code == 0, result.output
        frames[name] = [p.read_bytes() for p in sorted(folder.glob("*.png"))]
    assert len(frames["muted"]) == len(frames["base"]) > 2
    assert frames["muted"] == frames["base"]
    assert frames["layer"] != frames["base"]


def test_batch_applies_the_flags_to_the_takes_whose_stack_has_them(tmp_path, stack, rig):
    base, layer, other = stack
    out = tmp_path / "out"
    report = run_batch([str(base), str(layer), str(other)], out, rig=rig, formats="bvh",
                       fps=FPS, workers=1, layers=LayerOptions.from_flags(mute=[layer],
                                                                          strict=False))
    assert not report.failed, report.table()
    np.testing.assert_array_equal(_motion(out / "layer.bvh"), _motion(out / "base.bvh"))
    single = tmp_path / "other.bvh"
    assert _export(other, single).exit_code == 0
    np.testing.assert_array_equal(_motion(out / "other.bvh"), _motion(single))
    again = run_batch([str(layer)], out, rig=rig, formats="bvh", fps=FPS, workers=1,
                      resume=True)  # the flags shape the outputs: without them it is redone
    assert [row.state for row in again.rows] == ["done"], again.table()
    assert np.abs(_motion(out / "layer.bvh") - _motion(out / "base.bvh")).max() > 1.0
