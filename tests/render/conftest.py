"""One EGL context for the whole render test session, GL errors checked around every test,
and small procedural test meshes (a capped tube along x with smooth weights)."""

import numpy as np
import pytest

from puppet.render import create_context


@pytest.fixture(scope="session")
def gl_context():
    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.fixture(autouse=True)
def gl_errors(gl_context):
    """Fail a test that leaves a GL error behind, and refuse to start on a dirty context."""
    assert gl_context.error == "GL_NO_ERROR"
    yield
    assert gl_context.error == "GL_NO_ERROR"


def tube(segments: int = 40, sides: int = 16, length: float = 2.0, radius: float = 0.2):
    """A capped cylinder along +x from 0 to length: V (n, 3), F (f, 3) outward, counter-clockwise."""
    xs = np.linspace(0.0, length, segments)
    angles = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([np.zeros(sides), radius * np.cos(angles), radius * np.sin(angles)], axis=1)
    V = (ring[None, :, :] + np.stack([xs, 0 * xs, 0 * xs], 1)[:, None, :]).reshape(-1, 3)
    faces = []
    for i in range(segments - 1):
        for j in range(sides):
            a, b = i * sides + j, i * sides + (j + 1) % sides
            faces += [[a, b, a + sides], [b, b + sides, a + sides]]
    start, end = len(V), len(V) + 1
    V = np.vstack([V, [[0.0, 0.0, 0.0], [length, 0.0, 0.0]]])
    last = (segments - 1) * sides
    for j in range(sides):
        faces.append([start, (j + 1) % sides, j])
        faces.append([end, last + j, last + (j + 1) % sides])
    return V, np.array(faces, dtype=np.int32)


def two_bone_weights(V: np.ndarray, pivot_x: float, blend: float) -> np.ndarray:
    """W (n, 2): bone 0 left of pivot_x, bone 1 right of it, a smoothstep over width blend."""
    t = np.clip((V[:, 0] - pivot_x) / blend + 0.5, 0.0, 1.0)
    s = t * t * (3 - 2 * t)
    return np.stack([1 - s, s], axis=1)


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def handle_T(transforms) -> np.ndarray:
    """T (4m, 3) float32 from a list of (3, 4) affine transforms [A | t] (v' = A v + t)."""
    return np.concatenate([np.asarray(a, dtype=np.float64).T for a in transforms]).astype(np.float32)


def rotation_about(R: np.ndarray, pivot) -> np.ndarray:
    """(3, 4) affine rotating by R about pivot."""
    pivot = np.asarray(pivot, dtype=np.float64)
    return np.hstack([R, (pivot - R @ pivot)[:, None]])


IDENTITY = np.hstack([np.eye(3), np.zeros((3, 1))])


@pytest.fixture
def bar():
    """Two-bone bar: V, F, W for a tube of length 2 along x, bones split at x = 1."""
    V, F = tube()
    return V, F, two_bone_weights(V, 1.0, 0.3)


@pytest.fixture
def helpers():
    """The mesh and transform helpers above, for tests (conftest is not importable by name)."""

    class Helpers:
        pass

    h = Helpers()
    h.tube, h.two_bone_weights, h.rotation_z = tube, two_bone_weights, rotation_z
    h.handle_T, h.rotation_about, h.IDENTITY = handle_T, rotation_about, IDENTITY
    return h


@pytest.fixture(scope="session")
def posed_critter():
    """The built-in critter (26 handles: 18 bones and 8 extra weights) and a T solved from a pose."""
    from puppet.bus import Reading
    from puppet.loop import Pipeline
    from puppet.rig import builtin

    rig = builtin()
    pipeline = Pipeline(rig, render=False)
    k = len(rig.servo_map)
    ticks = (rig.servo_map.zero + 350 * np.sin(np.arange(k))).astype(np.int32)
    pipeline.solve(Reading(0, rig.servo_map.ids, ticks, np.ones(k, bool)))
    return rig, np.asarray(pipeline.model.weights), pipeline.T.copy(), pipeline.bone_segments
