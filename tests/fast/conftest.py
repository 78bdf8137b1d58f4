"""Small test meshes for the FAST solver tests (generated, a few thousand vertices)."""

import numpy as np
import pytest


def make_bar(nl=48, nr=20, length=4.0, radius=0.5, bones=3):
    """A closed-ring tube along x: V (nl*nr, 3), F triangles, smooth bone weights W (n, bones)."""
    x = np.linspace(0.0, length, nl)
    t = np.linspace(0.0, 2 * np.pi, nr, endpoint=False)
    X, A = np.meshgrid(x, t, indexing="ij")
    V = np.stack([X, radius * np.cos(A), radius * np.sin(A)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nl - 1), np.arange(nr), indexing="ij")
    a = (i * nr + j).ravel()
    b = (i * nr + (j + 1) % nr).ravel()
    F = np.concatenate([np.stack([a, b, b + nr], 1), np.stack([a, b + nr, a + nr], 1)])
    centres = (np.arange(bones) + 0.5) * length / bones
    W = np.exp(-(((V[:, :1] - centres[None]) / (0.45 * length / bones)) ** 2))
    W /= W.sum(1, keepdims=True)
    return V, F, W


def make_tet_block(nx=10, ny=4, nz=4, bones=3):
    """A tetrahedralised box along x: V, tets (6 per cube), bone weights along x."""
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1).reshape(-1, 3)
    V = g * np.array([4.0 / (nx - 1), 1.0 / (ny - 1), 1.0 / (nz - 1)])
    idx = np.arange(nx * ny * nz).reshape(nx, ny, nz)
    T = []
    for x in range(nx - 1):
        for y in range(ny - 1):
            for z in range(nz - 1):
                c = [idx[x + dx, y + dy, z + dz] for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]
                # Kuhn subdivision of the cube (corner 0 to corner 7).
                for p in ((1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)):
                    T.append([c[0], c[p[0]], c[p[1]], c[7]])
    T = np.array(T)
    centres = (np.arange(bones) + 0.5) * 4.0 / bones
    W = np.exp(-(((V[:, :1] - centres[None]) / (0.45 * 4.0 / bones)) ** 2))
    W /= W.sum(1, keepdims=True)
    return V, T, W


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="session")
def bar():
    return make_bar()


@pytest.fixture(scope="session")
def bar_model(bar):
    from puppet.fast import FastModel

    V, F, W = bar
    return FastModel(V, F, W, clusters=16, extra_weights=2, energy="spokes_and_rims", cache_dir=False)


@pytest.fixture(scope="session")
def helpers():
    """The mesh and rotation generators above, for tests that need other sizes."""
    from types import SimpleNamespace

    return SimpleNamespace(make_bar=make_bar, make_tet_block=make_tet_block, random_rotation=random_rotation, rot_z=rot_z)
