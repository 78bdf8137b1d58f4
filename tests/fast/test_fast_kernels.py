"""The native kernel sets (baseline build, AVX2+FMA, AVX-512 on 8-lane vectors; the best the CPU has
is selected at run time, PUPPET_SIMD caps it) give the same solve, and in each the interleaved
rotation fit (several batches of eight in flight) agrees with the plain one-batch-at-a-time schedule
to float32 rounding."""

import json
import os
import subprocess
import sys

import numpy as np

SCRIPT = r"""
import json, sys
import numpy as np
from puppet import _native
from puppet.fast import FastModel, Pattern

x = np.linspace(0, 4, 30); a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
X, A = np.meshgrid(x, a, indexing="ij")
V = np.stack([X, 0.5 * np.cos(A), 0.5 * np.sin(A)], -1).reshape(-1, 3)
i, j = np.meshgrid(np.arange(29), np.arange(12), indexing="ij")
p = (i * 12 + j).ravel(); q = (i * 12 + (j + 1) % 12).ravel()
F = np.concatenate([np.stack([p, q, q + 12], 1), np.stack([p, q + 12, p + 12], 1)])
W = np.exp(-((V[:, :1] - np.array([[0.7, 2.0, 3.3]])) / 0.6) ** 2); W /= W.sum(1, keepdims=True)
model = FastModel(V, F, W, clusters=13, extra_weights=1, cache_dir=False)
pattern = Pattern(full=(0,), relative=((1, 0, (1.3, 0, 0)),))
values = pattern.values()
values.full[0] = model.rest_T()[:4]
c, s = np.cos(0.7), np.sin(0.7)
values.relative[0] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32)
T = model.rest_T()
stats = model.solver(pattern).solve(values, T, iterations=6, accelerate=False)
S = np.random.default_rng(0).normal(size=(37, 3, 3)).astype(np.float32); R = np.empty_like(S)
_native.fit_rotations(S, R)
# Interleaved against plain: 59 random matrices (7 batches and a padded one: groups of 3, 2, 2,
# and a lone batch of 1), and 1000 with every seventh near the identity (converged lanes grouped
# with slow ones: the group's extra sweeps must not move them beyond rounding).
rng = np.random.default_rng(1)
agree = {}
for n in (59, 1000):
    Sn = rng.normal(size=(n, 3, 3)).astype(np.float32)
    Sn[::7] = np.eye(3, dtype=np.float32) + np.float32(1e-3) * Sn[::7]
    Rn = {il: np.empty_like(Sn) for il in range(1, _native.rotation_interleave + 1)}
    for il in Rn:
        _native.fit_rotations(Sn, Rn[il], interleave=il)
    agree[n] = {"max_diff": max(float(np.abs(Rn[il] - Rn[1]).max()) for il in Rn),
                "det_err": max(float(np.abs(np.linalg.det(Rn[il].astype(np.float64)) - 1).max()) for il in Rn)}
# A well-conditioned set (rotations times SPD stretches 0.5..2): the fit is insensitive there,
# so schedules must agree to a few float32 ulps.
q = rng.normal(size=(200, 4)); q /= np.linalg.norm(q, axis=1, keepdims=True)
w, x, y, z = q.T
Q = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
              np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
              np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)
D = np.zeros((200, 3, 3)); D[:, [0, 1, 2], [0, 1, 2]] = rng.uniform(0.5, 2.0, size=(200, 3))
Sw = (Q @ D).astype(np.float32)
Rw = {il: np.empty_like(Sw) for il in (1, _native.rotation_interleave)}
for il in Rw:
    _native.fit_rotations(Sw, Rw[il], interleave=il)
agree["well"] = {"max_diff": float(np.abs(Rw[_native.rotation_interleave] - Rw[1]).max()),
                 "to_truth": float(np.abs(Rw[_native.rotation_interleave] - Q).max())}
print(json.dumps({"simd": _native.simd, "T": T.tolist(), "E": stats.energy, "R": R.tolist(), "agree": agree}))
"""


def run(env_extra):
    env = dict(os.environ, **env_extra)
    # Run outside the checkout so that the installed package (with its built module) is imported.
    out = subprocess.run([sys.executable, "-P", "-c", SCRIPT], env=env, capture_output=True, text=True,
                         check=True, cwd=os.path.dirname(os.path.abspath(__file__)))
    return json.loads(out.stdout)


def cpu_flags() -> set:
    """This CPU's feature flags (Linux /proc/cpuinfo; empty elsewhere)."""
    try:
        with open("/proc/cpuinfo") as f:
            return set(next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), []))
    except OSError:
        return set()


def expected_sets() -> dict:
    """PUPPET_SIMD setting -> the kernel set it must select on this CPU."""
    flags = cpu_flags()
    avx2 = {"avx2", "fma"} <= flags
    avx512 = avx2 and {"avx512f", "avx512vl", "avx512dq", "avx512bw"} <= flags
    return {"avx2": "avx2+fma" if avx2 else None, "": "avx512" if avx512 else ("avx2+fma" if avx2 else None)}


def test_generic_and_selected_kernels_agree():
    generic = run({"PUPPET_SIMD": "generic"})
    # The default build's baseline is below AVX2 (a -march=native build, PUPPET_NATIVE_ARCH, is
    # for benchmarks only), so forcing generic gives the baseline set; a CPU with AVX2+FMA gets the
    # AVX2+FMA set at run time (PUPPET_SIMD=avx2 caps it there), one with AVX-512 the AVX-512 set.
    assert generic["simd"] in ("sse2", "avx", "scalar")
    for setting, want in expected_sets().items():
        chosen = run({"PUPPET_SIMD": setting})
        # Each run must use the set named, or the comparison below proves nothing.
        assert chosen["simd"] == (want or generic["simd"]), setting
        np.testing.assert_allclose(np.array(generic["T"]), np.array(chosen["T"]), atol=2e-5)
        np.testing.assert_allclose(np.array(generic["R"]), np.array(chosen["R"]), atol=2e-5)
        assert abs(generic["E"] - chosen["E"]) <= 1e-4 * max(1.0, abs(chosen["E"]))


def test_interleaved_rotation_fit_agrees_with_the_plain_schedule_in_every_kernel_set():
    from puppet import _native

    assert _native.rotation_interleave >= 2  # there is an interleaved schedule to compare
    for env in ({"PUPPET_SIMD": "generic"}, {"PUPPET_SIMD": "avx2"}, {"PUPPET_SIMD": ""}):
        agree = run(env)["agree"]
        # Random matrices include ill-conditioned ones (close singular values), where a rounding-
        # level change in the eigenbasis moves the rotation by ulps times the conditioning: the
        # bound the fit has against a float64 SVD (tests/foundation/test_native.py).
        for n in ("59", "1000"):
            assert agree[n]["max_diff"] <= 2e-5, (env, n, agree[n])
            assert agree[n]["det_err"] <= 1e-5, (env, n, agree[n])
        assert agree["well"]["max_diff"] <= 1e-6, (env, agree["well"])
        assert agree["well"]["to_truth"] <= 2e-6, (env, agree["well"])


def test_fit_rotations_refuses_an_interleave_out_of_range():
    import pytest

    from puppet import _native

    S = np.zeros((8, 3, 3), np.float32)
    R = np.empty_like(S)
    for bad in (0, _native.rotation_interleave + 1):
        with pytest.raises(ValueError, match="interleave"):
            _native.fit_rotations(S, R, interleave=bad)
