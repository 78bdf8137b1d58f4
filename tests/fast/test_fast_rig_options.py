"""Rig-file options of the live solve ([[contact]], [solver.dynamics], on_dropout): parsed into
the rig, used by its pattern, and bad values refused with the file and line named."""

import numpy as np
import pytest

from puppet.fast import FastModel
from puppet.rig.errors import RigError
from puppet.rig.load import BUILTIN_RIG, load_rig

TAIL_TIP = 12279  # the built-in rig's pin


def write_rig(tmp_path, extra: str, *, drop_pin: bool = False, top: str = ""):
    """The built-in rig file with ``top`` inserted before its tables and ``extra`` appended; the
    mesh path is made absolute. Returns the new file's path."""
    text = BUILTIN_RIG.read_text()
    text = text.replace('mesh = "critter.npz"', f'mesh = "{BUILTIN_RIG.parent / "critter.npz"}"')
    if drop_pin:
        text = text[: text.index("[[pin]]")]
    head, tail = text.split("[solver]", 1)
    path = tmp_path / "critter.toml"
    path.write_text(head + top + "\n[solver]" + tail + "\n" + extra)
    return path


def line_of(path, needle):
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if needle in line)


def test_contact_holds_its_axes_only(tmp_path):
    path = write_rig(tmp_path, f"[[contact]]\nvertex = {TAIL_TIP}\naxes = \"y\"\nvalue = 0.02\n", drop_pin=True)
    rig = load_rig(path)
    assert rig.contacts == ((TAIL_TIP, "y", (rig.V[TAIL_TIP, 0], 0.02, rig.V[TAIL_TIP, 2])),)
    pattern = rig.pattern()
    assert pattern.contacts == ((TAIL_TIP, "y"),) and pattern.positional == ()
    options = rig.solver_options
    model = FastModel(rig.V, rig.F, rig.W, clusters=options.clusters, extra_weights=options.extra_weights,
                      energy=options.energy)
    values = pattern.values()
    angles = np.zeros(len(rig.servo_map))
    angles[9] = angles[12] = np.radians(40)  # both thighs swing: the hips stay, the tail follows
    rig.fill_values(angles, values)
    T = model.rest_T()
    model.solver(pattern).solve(values, T, iterations=60)
    tip = model.deform(T)[TAIL_TIP]
    diag = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    assert abs(tip[1] - 0.02) <= 1e-5 * diag


def test_point_contact_takes_the_nearest_vertex_and_rest_values(tmp_path):
    path = write_rig(tmp_path, "[[contact]]\npoint = [0.0, 0.0, 0.0]\naxes = [\"x\", \"z\"]\n")
    rig = load_rig(path)
    v = int(np.argmin((rig.V**2).sum(1)))
    assert rig.contacts == ((v, "xz", tuple(rig.V[v])),)


@pytest.mark.parametrize(
    "extra, needle, field, message",
    [
        ("[[contact]]\nvertex = 999999\naxes = \"y\"\n", "vertex = 999999", "contact 1 vertex", "out of range"),
        ("[[contact]]\nvertex = 3\naxes = \"yw\"\n", "axes = \"yw\"", "contact 1 axes", "distinct letters"),
        ("[[contact]]\nvertex = 3\naxes = \"xy\"\nvalue = [1.0]\n", "value = [1.0]", "contact 1 value", "2 numbers"),
        ("[solver.dynamics]\ndensity = -1.0\n", "density = -1.0", "solver.dynamics.density",
         "must be a number 0..1000 mass per unit area, got -1.0"),
        ("[solver.dynamics]\ndt = 1e300\n", "dt = 1e300", "solver.dynamics.dt",
         "must be a number 0.0001..1 s, got 1e+300"),
        ("[solver.dynamics]\ngravity = [0, 1e308, 0]\n", "gravity = [0, 1e308, 0]", "solver.dynamics.gravity",
         "each a number -100000..100000 model units/s^2"),
        ("[[contact]]\nvertex = 3\naxes = \"y\"\nvalue = 1e308\n", "value = 1e308", "contact 1 value",
         "each a number -1000000..1000000 model units"),
        ("[solver.dynamics]\ndt = 0\n", "dt = 0", "solver.dynamics.dt", "time step dt must be"),
        ("[solver.dynamics]\nmass = 3\n", "mass = 3", "solver.dynamics.mass", "unknown option"),
    ],
)
def test_bad_options_name_file_and_line(tmp_path, extra, needle, field, message):
    path = write_rig(tmp_path, extra)
    with pytest.raises(RigError) as info:
        load_rig(path)
    err = info.value
    assert (err.path, err.line, err.field) == (str(path), line_of(path, needle), field)
    assert message in str(err)


def test_bad_dropout_mode_names_line(tmp_path):
    path = write_rig(tmp_path, "", top='on_dropout = "drop"\n')
    with pytest.raises(RigError) as info:
        load_rig(path)
    assert (info.value.line, info.value.field) == (line_of(path, "on_dropout"), "on_dropout")
    text = path.read_text().replace('on_dropout = "drop"\n', "").replace("id = 3\n", 'id = 3\non_dropout = "gone"\n')
    path.write_text(text)
    with pytest.raises(RigError) as info:
        load_rig(path)
    assert (info.value.line, info.value.field) == (line_of(path, 'on_dropout = "gone"'), "servo 3 on_dropout")


def test_dropout_and_dynamics_options_are_read(tmp_path):
    path = write_rig(tmp_path, "[solver.dynamics]\ndensity = 3.5\ndamping = 0.5\ngravity = [0, -1, 0]\n",
                     top='on_dropout = "free"\ndropout_ms = 200\n')
    path.write_text(path.read_text().replace("id = 2\n", 'id = 2\non_dropout = "hold"\n'))
    rig = load_rig(path)
    extras = rig.extras
    assert (extras.on_dropout, extras.dropout_ms, extras.servo_dropout) == ("free", 200.0, {2: "hold"})
    assert extras.dropout_mode(2) == "hold" and extras.dropout_mode(3) == "free"
    d = extras.dynamics
    assert (d.density, d.damping, d.gravity) == (3.5, 0.5, (0.0, -1.0, 0.0))
    assert rig.solver_options.clusters == 100  # [solver] itself still read
