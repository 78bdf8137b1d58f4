"""Joint limits on free bones, enforced inside the solve: an extreme sensed pose of the built-in
character folds its free spine past 5 degrees without limits, not with them, while every sensed
joint still matches its servos exactly."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from puppet.fast import FastModel, Pattern, PatternError
from puppet.rig.errors import RigError
from puppet.rig.load import load_rig

from .test_fast_rig_options import line_of, write_rig

LIMITS = """
[[limit]]
bone = "spine"
swing_deg = 5
twist_deg = [-5, 5]

[[limit]]
bone = "chest"
swing_deg = 5
twist_deg = [-5, 5]
"""


def relative_rotation(T, child, parent):
    """Closest rotation R with A_child = A_parent R (A: the handles' linear parts)."""
    B = T.reshape(-1, 4, 3).astype(np.float64)
    X = np.linalg.solve(B[parent, :3].T, B[child, :3].T)
    U, _, Vt = np.linalg.svd(X)
    return U @ Vt


def swing_twist_deg(R, d):
    """Swing (angle of the cone about d) and twist (about d) of R, degrees: R = swing @ twist."""
    twist = Rotation.from_rotvec(d * 0.0)
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    s = np.dot((x, y, z), d)
    if np.hypot(w, s) > 1e-12:
        q = np.array([*(s * d), w]) / np.hypot(w, s)
        twist = Rotation.from_quat(q)
    swing = Rotation.from_matrix(R) * twist.inv()
    t = twist.as_rotvec() @ d
    return np.degrees(np.linalg.norm(swing.as_rotvec())), np.degrees(t)


@pytest.fixture(scope="module")
def limited(tmp_path_factory):
    rig = load_rig(write_rig(tmp_path_factory.mktemp("limits"), LIMITS))
    o = rig.solver_options
    model = FastModel(rig.V, rig.F, rig.W, clusters=o.clusters, extra_weights=o.extra_weights, energy=o.energy)
    return rig, model


def extreme_angles(rig):
    """Neck, head and both upper arms at their servo limits: the free spine takes the load."""
    angles = np.zeros(len(rig.servo_map))
    for k, servo in enumerate(rig.servo_map.servos):
        if servo.joint in ("neck", "head"):
            angles[k] = servo.limits[1]
        elif servo.joint.startswith("upperarm"):
            angles[k] = servo.limits[1] if servo.sign > 0 else servo.limits[0]
    return angles


def test_limits_hold_the_spine_and_sensed_joints_stay_exact(limited):
    rig, model = limited
    pattern = rig.pattern()
    assert [names for names in (rig.skeleton.names[c] for c, *_ in pattern.limits)] == ["spine", "chest"]
    free = Pattern(full=pattern.full, relative=pattern.relative, positional=pattern.positional)
    values = pattern.values()
    rig.fill_values(extreme_angles(rig), values)
    T_free, T_lim = model.rest_T(), model.rest_T()
    model.solver(free).solve(values, T_free, iterations=200)
    solver = model.solver(pattern)
    solver.solve(values, T_lim, iterations=200)
    assert solver.active_limits >= 1
    for c, p, d, swing, lo, hi in pattern.limits:
        d = np.array(d)
        s_free, t_free = swing_twist_deg(relative_rotation(T_free, c, p), d)
        s_lim, t_lim = swing_twist_deg(relative_rotation(T_lim, c, p), d)
        assert max(s_free, abs(t_free)) > 7.0  # folds past the limit without it
        assert s_lim <= 5.0 + 1e-3 and -5.0 - 1e-3 <= t_lim <= 5.0 + 1e-3
    blocks = T_lim.reshape(-1, 4, 3)
    for q, j in enumerate(pattern.full):
        assert np.abs(blocks[j] - values.full[q]).max() <= 1e-5
    for q, (c, p, _) in enumerate(pattern.relative):
        assert np.abs(relative_rotation(T_lim, c, p) - values.relative[q]).max() <= 1e-5


def test_limits_change_nothing_inside_them(limited):
    rig, model = limited
    pattern = rig.pattern()
    wide = Pattern(full=pattern.full, relative=pattern.relative, positional=pattern.positional,
                   limits=tuple((c, p, d, np.pi, -np.pi, np.pi) for c, p, d, *_ in pattern.limits))
    free = Pattern(full=pattern.full, relative=pattern.relative, positional=pattern.positional)
    values = pattern.values()
    angles = extreme_angles(rig) * 0.3
    rig.fill_values(angles, values)
    T_wide, T_free = model.rest_T(), model.rest_T()
    solver = model.solver(wide)
    solver.solve(values, T_wide, iterations=10, accelerate=False)  # the same plain steps
    model.solver(free).solve(values, T_free, iterations=10, accelerate=False)
    assert solver.active_limits == 0
    assert np.array_equal(T_wide, T_free)


def test_limit_pattern_errors(limited):
    rig, model = limited
    pattern = rig.pattern()
    hips = pattern.full[0]
    with pytest.raises(PatternError, match=r"limits\[0\]: handle 0 must be free"):
        model.solver(Pattern(full=pattern.full, limits=((hips, 1, (0.0, 1.0, 0.0), 0.1, -0.1, 0.1),)))
    with pytest.raises(PatternError, match=r"limits\[0\]: need 0 <= swing"):
        model.solver(Pattern(full=pattern.full, limits=((1, 0, (0.0, 1.0, 0.0), 0.1, 0.2, 0.1),)))


@pytest.mark.parametrize(
    "extra, needle, field, message",
    [
        ('[[limit]]\nbone = "chest"\ntwist_deg = [10, -10]\n', "twist_deg = [10, -10]", "limit 1 twist_deg",
         "min 10 > max -10"),
        ('[[limit]]\nbone = "tentacle"\nswing_deg = 10\n', 'bone = "tentacle"', "limit 1 bone", "unknown bone"),
        ('[[limit]]\nbone = "chest"\nswing_deg = -3\n', "swing_deg = -3", "limit 1 swing_deg", "0..180"),
    ],
)
def test_bad_limits_name_file_and_line(tmp_path, extra, needle, field, message):
    path = write_rig(tmp_path, extra)
    with pytest.raises(RigError) as info:
        load_rig(path)
    assert (info.value.path, info.value.line, info.value.field) == (str(path), line_of(path, needle), field)
    assert message in str(info.value)
