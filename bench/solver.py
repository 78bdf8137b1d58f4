"""Benchmark the FAST solver on a ~43k-vertex / 86k-triangle test character built here.

Cases (libigl arap_dof on this machine kind: 9.6 / 42 / 85 us per iteration):
  m=5 r=50;  m=24 r=100;  m=25 (5 bones + 20 extra weights) r=200.
Per case: median us per iteration over >= 200 warm-started frames (10 iterations each, plain and
accelerated), precompute seconds (no cache, median of 3), refactor ms (model.solver(pattern)), iterations to
reach a fixed energy with and without acceleration, and two baselines measured in the same run on
the same mesh: a plain NumPy implementation of the same iteration (us per iteration) and libigl's
full-space igl.arap_solve (ms per iteration).

    python bench/solver.py --json out.json [--frames 200] [--quick]

Clock: every per-iteration, per-call and baseline time is the CPU time of the timing thread
(time.thread_time_ns; libigl's baseline: the process's CPU time), so a run descheduled on a shared
machine neither passes nor fails a ratio; precompute and refactor times stay wall-clock (they may
use several threads). Beside each case: GFLOP/s by a flop model of the iteration (flops_per_iter)
and its fraction of this core's single-precision peak, measured in the same run (peak_gflops:
float32 matrix products, single-threaded BLAS, the best of several). The 1-minute load average is
printed and stored with the figures.

Also: the live-solve cases (dynamics on, the tolerance stop, the dropout pattern switch on the
built-in character), and, when a -march=native build of the module exists in build/native-arch
(cmake -S . -B build/native-arch -DPUPPET_NATIVE_ARCH=ON && cmake --build build/native-arch),
its per-iteration times next to this (portable, runtime-dispatched) build's.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

# Single-threaded BLAS: on a shared 2-core machine OpenBLAS's spinning worker threads steal the
# core the solver runs on (and the targets are single-threaded figures).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def _use_module(argv):
    """--module SO: load that build of puppet._native (e.g. the -march=native one) instead."""
    if "--module" in argv:
        import importlib.machinery
        import importlib.util

        path = argv[argv.index("--module") + 1]
        loader = importlib.machinery.ExtensionFileLoader("puppet._native", path)
        spec = importlib.util.spec_from_file_location("puppet._native", path, loader=loader)
        module = importlib.util.module_from_spec(spec)
        loader.exec_module(module)
        sys.modules["puppet._native"] = module


_use_module(sys.argv)

cpu_ns = time.thread_time_ns
"""The bench's clock: CPU time of the calling thread (ns)."""

ROTATION_FLOPS = 800
"""Flops of one closest-rotation fit (solver_native/src/kernels_impl.inc, polar) with two Jacobi
sweeps, what a warm-started frame takes (one or two): 408 + 197 per sweep, counting a multiply-add
as two and a select or comparison as none."""


def flops_per_iter(model):
    """The flop model of one plain iteration, unpadded: the covariance gather S = K^T T over K's
    nonzero entries (3r x 4m by 4m x 3: the kernel skips the zero columns of compactly supported
    extra weights), r rotation fits, the global product G R (4m x 3r by 3r x 3, dense)."""
    m, r = model.m, model.r
    return 2 * np.count_nonzero(model.K) * 3 + r * ROTATION_FLOPS + 2 * (4 * m) * (3 * r) * 3


def peak_gflops(n=256, reps=40):
    """This core's measured single-precision peak: the best rate of float32 n x n matrix products
    (single-threaded BLAS, see OPENBLAS_NUM_THREADS above), GFLOP/s in thread CPU time."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(n, n)).astype(np.float32), rng.normal(size=(n, n)).astype(np.float32)
    c = np.empty((n, n), np.float32)
    np.matmul(a, b, out=c)
    best = float("inf")
    for _ in range(reps):
        t0 = cpu_ns()
        np.matmul(a, b, out=c)
        best = min(best, cpu_ns() - t0)
    return 2 * n**3 / best
from puppet import _native  # noqa: E402
from puppet.fast import FastModel, Pattern  # noqa: E402


def character(rings=240, segments=180, length=8.0):
    """A wavy, tapered tube along x: V (rings*segments, 3), F (2*(rings-1)*segments, 3)."""
    x = np.linspace(0.0, length, rings)
    a = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    X, A = np.meshgrid(x, a, indexing="ij")
    radius = 0.6 + 0.25 * np.sin(X * 1.3) + 0.08 * np.cos(3 * A) * np.sin(X * 0.7)
    Y = radius * np.cos(A) + 0.3 * np.sin(X * 0.5)
    Z = 0.8 * radius * np.sin(A)
    V = np.stack([X, Y, Z], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(rings - 1), np.arange(segments), indexing="ij")
    p = (i * segments + j).ravel()
    q = (i * segments + (j + 1) % segments).ravel()
    F = np.concatenate([np.stack([p, q, q + segments], 1), np.stack([p, q + segments, p + segments], 1)])
    return V, F


def bone_weights(V, bones, length=8.0):
    """(n, bones) smooth partition of unity along x."""
    centres = (np.arange(bones) + 0.5) * length / bones
    W = np.exp(-(((V[:, :1] - centres[None]) / (0.5 * length / bones)) ** 2))
    return W / W.sum(1, keepdims=True)


def rot(axis, angle):
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def frame_targets(V0, pins, f, diag, rng_axes):
    """Positional targets of frame f: a bend about z through the origin growing along the body,
    plus a per-pin wobble of 5% of the diagonal."""
    P = V0[list(pins)]
    out = np.empty_like(P)
    for k, p in enumerate(P):
        bend = rot(np.array([0.0, 0.0, 1.0]), 0.5 * np.sin(2 * np.pi * f / 90) * p[0] / 8.0)
        wob = rot(rng_axes[k], 0.5 * np.sin(2 * np.pi * f / 60 + k))
        out[k] = bend @ (wob @ np.zeros(3) + p) + 0.05 * diag * np.sin(2 * np.pi * f / 75 + k) * rng_axes[k]
    return out.astype(np.float32)


def numpy_iteration_us(model, solver, values, T0, iters=100):
    """Plain NumPy (float64) of the same local/global iteration: S = K^T T, batched SVD, T = G Rt + Tb."""
    K = model.K
    G = solver.factor.G
    P2 = solver.factor.P2
    b = np.vstack([values.full.reshape(-1, 3), values.positional]).astype(np.float64)
    Tb = P2 @ b
    T = T0.astype(np.float64)
    r = model.r

    def step(T):
        C = (K.T @ T).reshape(r, 3, 3).transpose(0, 2, 1)
        U, _, Vt = np.linalg.svd(C)
        d = np.sign(np.linalg.det(U @ Vt))
        U[:, :, 2] *= d[:, None]
        R = U @ Vt
        return G @ R.transpose(0, 2, 1).reshape(3 * r, 3) + Tb

    for _ in range(5):
        T = step(T)
    t0 = cpu_ns()
    for _ in range(iters):
        T = step(T)
    return (cpu_ns() - t0) / iters / 1e3


def full_arap_ms(V, F, pins, targets, calls=4):
    import igl

    data = igl.ARAPData()
    data.max_iter = 1
    b = np.asarray(pins, np.int32)
    igl.arap_precomputation(V, F.astype(np.int64), 3, b, data)
    U = V.copy()
    bc = targets.astype(np.float64)
    U = igl.arap_solve(bc, data, U)
    times = []
    for _ in range(calls):
        t0 = time.process_time_ns()  # CPU time of every thread (libigl may use several)
        U = igl.arap_solve(bc, data, U)
        times.append(time.process_time_ns() - t0)
    return statistics.median(times) / 1e6


def iterations_to_energy(solver, values, T0, cap=1000):
    """Iterations each variant needs to close 99.9% of the gap from iteration 1 to the converged energy."""
    T = T0.copy()
    solver.solve(values, T, iterations=cap, accelerate=False, history=True)
    plain = solver.history.copy()
    T = T0.copy()
    solver.solve(values, T, iterations=cap, accelerate=True, history=True)
    accel = solver.history.copy()
    e_inf = min(plain[1:].min(), accel[1:].min())  # history[0] is the previous pose's energy
    target = e_inf + 1e-3 * (plain[1] - e_inf)

    def first(h):
        hit = np.flatnonzero(h[1:] <= target)
        return int(hit[0]) + 1 if hit.size else cap

    return first(plain), first(accel)


def run_case(name, V, F, bones, extra, r, frames, quick):
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    W = bone_weights(V, bones)
    runs = []
    for _ in range(1 if quick else 3):  # median of 3: the first run in a process pays page faults
        t0 = time.perf_counter()
        model = FastModel(V, F, W, clusters=r, extra_weights=extra, energy="spokes_and_rims", cache_dir=False)
        runs.append(time.perf_counter() - t0)
    precompute = statistics.median(runs)
    pins = tuple(int(np.argmax(W[:, j])) for j in range(bones))
    pattern = Pattern(positional=pins)
    refactor = []
    for _ in range(3 if quick else 7):
        t0 = time.perf_counter()
        solver = model.solver(pattern)
        refactor.append(time.perf_counter() - t0)
    values = pattern.values()
    axes = np.random.default_rng(1).normal(size=(len(pins), 3))
    T = model.rest_T()
    per_iter = {}
    for accelerate in (False, True):
        T = model.rest_T()
        times = []
        for f in range(frames + 20):
            values.positional[:] = frame_targets(V, pins, f, diag, axes)
            t0 = cpu_ns()
            solver.solve(values, T, iterations=10, accelerate=accelerate)
            dt = cpu_ns() - t0
            if f >= 20:
                times.append(dt / 10 / 1e3)
        per_iter[accelerate] = statistics.median(times)
    # A hard frame: a big jump from the rest pose.
    values.positional[:] = frame_targets(V, pins, 22, diag, axes)
    iters_plain, iters_accel = iterations_to_energy(solver, values, model.rest_T(), cap=300 if quick else 1000)
    numpy_us = numpy_iteration_us(model, solver, values, T, iters=30 if quick else 100)
    full_ms = full_arap_ms(V, F, pins, values.positional, calls=2 if quick else 4)
    flops = flops_per_iter(model)
    return {
        "name": name,
        "flops_per_iter": flops,
        "gflops": flops / per_iter[False] / 1e3,
        "n": int(V.shape[0]),
        "f": int(F.shape[0]),
        "m": model.m,
        "r": model.r,
        "us_per_iter": per_iter[False],
        "us_per_iter_accel": per_iter[True],
        "precompute_s": precompute,
        "refactor_ms": statistics.median(refactor) * 1e3,
        "iters_plain": iters_plain,
        "iters_accel": iters_accel,
        "numpy_us_per_iter": numpy_us,
        "full_arap_ms_per_iter": full_ms,
    }


def _vertex_error(M, T, Vc, diag):
    """Largest per-vertex distance |M T - Vc| (Euclidean), as a fraction of the diagonal."""
    return float(np.linalg.norm(M @ T - Vc, axis=1).max() / diag)


def tol_case(tols=(1e-3, 1e-4, 1e-5), budgets=(10, 20, 30, 50), frames=30, target=1e-4):
    """The tolerance stop on the built-in character (its own pattern, the demo performance at 30
    frames per second, warm-started, accelerated). For each tol and each fixed budget (each its own
    warm-start chain): iterations per frame (mean, max) and the largest per-vertex distance from the
    converged result (a 3000-iteration solve from the same start), in % of the bounding-box
    diagonal. At tol = target (tol means a fraction of the diagonal): the fixed budget that keeps
    every frame within target, found from the per-frame need (the fewest iterations from the tol
    path's start reaching target) and checked on its own fixed-budget chain (raised until every
    frame of that chain is within target)."""
    from puppet.demo import Performance
    from puppet.rig import builtin

    rig = builtin()
    o = rig.solver_options
    model = FastModel(rig.V, rig.F, rig.W, clusters=o.clusters, extra_weights=o.extra_weights, energy=o.energy)
    pattern = rig.pattern()
    solver, reference = model.solver(pattern), model.solver(pattern)
    values = pattern.values()
    M = model.lbs_matrix()
    diag = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0)))
    perf = Performance(rig)
    ids = [s.id for s in rig.servo_map.servos]
    ticks = [np.array([perf.position(i, f / 30) for i in ids]).round().astype(np.int32) for f in range(frames)]

    def chain(iterations, tol, need=None):
        """One warm-started run over the frames: (iterations per frame, errors per frame)."""
        T = model.rest_T()
        iters, errs = [], []
        for f in range(frames):
            rig.fill_values(rig.servo_map.angles(ticks[f]), values)
            start = T.copy()
            Tc = start.copy()
            reference.solve(values, Tc, iterations=3000)
            Vc = M @ Tc
            iters.append(solver.solve(values, T, iterations=iterations, tol=tol).iterations)
            errs.append(_vertex_error(M, T, Vc, diag))
            if need is not None:
                Tk = start.copy()
                for k in range(1, 1001):  # the same solve with a fixed count k
                    Tk[:] = start
                    solver.solve(values, Tk, iterations=k)
                    if _vertex_error(M, Tk, Vc, diag) <= target:
                        break
                need.append(k)
        return iters, errs

    def summary(iters, errs):
        return {"iters_mean": float(np.mean(iters)), "iters_max": int(max(iters)),
                "err_max_pct_of_diag": 100 * max(errs), "err_mean_pct_of_diag": 100 * float(np.mean(errs))}

    out = {"frames": frames, "target": target, "runs": {}}
    need = []
    for t in tols:
        out["runs"][f"tol {t:g}"] = summary(*chain(1000, t, need if t == target else None))
    for k in budgets:
        out["runs"][f"fixed {k}"] = summary(*chain(k, None))
    # The stop test's cost: 10 iterations per frame with a tol too small to stop (the test runs
    # every iteration) against no tol, interleaved frame by frame, accelerated and plain.
    timed, timed_tol = model.solver(pattern), model.solver(pattern)  # the chains' solvers stay as they were
    for accelerate in (True, False):
        T0, T1 = model.rest_T(), model.rest_T()
        plain_us, tol_us = [], []
        for f in range(max(frames, 30)):
            rig.fill_values(rig.servo_map.angles(ticks[f % frames]), values)
            t0 = cpu_ns()
            n = timed.solve(values, T0, iterations=10, accelerate=accelerate).iterations
            t1 = cpu_ns()
            k = timed_tol.solve(values, T1, iterations=10, tol=1e-12, accelerate=accelerate).iterations
            t2 = cpu_ns()
            plain_us.append((t1 - t0) / n / 1e3)
            tol_us.append((t2 - t1) / k / 1e3)
        key = "accel" if accelerate else "plain"
        out[f"us_per_iter_{key}"] = statistics.median(plain_us)
        out[f"us_per_iter_{key}_tol"] = statistics.median(tol_us)
    if need:
        budget = max(need)
        while True:  # the per-frame need from another chain's starts: check it on its own chain
            errs = chain(budget, None)[1]
            if max(errs) <= target or budget >= 1000:
                break
            budget += 1
        out["runs"][f"fixed {budget}"] = summary([budget], errs)
        tol_run = out["runs"][f"tol {target:g}"]
        out["fixed_budget"] = budget
        out["per_frame_need_mean"] = float(np.mean(need))
        out["tol_iters_mean"] = tol_run["iters_mean"]
        out["tol_iters_max"] = tol_run["iters_max"]
        out["tol_err_max_pct_of_diag"] = tol_run["err_max_pct_of_diag"]
        out["tol_within_target"] = tol_run["err_max_pct_of_diag"] <= 100 * target
        out["tol_over_fixed"] = tol_run["iters_mean"] / budget
    return out


def per_iter_us(solver, values, V, pins, diag, axes, frames, model):
    T = model.rest_T()
    times = []
    for f in range(frames + 20):
        values.positional[:] = frame_targets(V, pins, f, diag, axes)
        t0 = cpu_ns()
        solver.solve(values, T, iterations=10)
        if f >= 20:
            times.append((cpu_ns() - t0) / 10 / 1e3)
    return statistics.median(times)


def live_cases(V, F, frames, quick):
    """m=5, r=50 again: the per-iteration time without dynamics or limits (accelerated: the
    baseline of this block), with dynamics on and with joint limits."""
    from puppet.fast import Dynamics

    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    W = bone_weights(V, 5)
    model = FastModel(V, F, W, clusters=50, energy="spokes_and_rims", cache_dir=False)
    pins = tuple(int(np.argmax(W[:, j])) for j in range(5))
    pattern = Pattern(positional=pins)
    axes = np.random.default_rng(1).normal(size=(len(pins), 3))
    values = pattern.values()
    plain = model.solver(pattern)
    dyn = model.solver(pattern, dynamics=Dynamics(dt=1 / 60, density=1e-3, damping=0.9, gravity=(0, -9.8, 0)))
    # Joint limits between consecutive bones (5 degree cone and twist about x): active every frame.
    five = np.radians(5.0)
    limits = tuple((j, j - 1, (1.0, 0.0, 0.0), five, -five, five) for j in range(1, 5))
    limited = model.solver(Pattern(positional=pins, limits=limits))
    out = {
        "us_per_iter": per_iter_us(plain, values, V, pins, diag, axes, frames, model),
        "dynamics_us_per_iter": per_iter_us(dyn, values, V, pins, diag, axes, frames, model),
        "limits_us_per_iter": per_iter_us(limited, values, V, pins, diag, axes, frames, model),
        "limits_active": limited.active_limits,
    }
    return out


def builtin_limits_case(frames):
    """The built-in character in an extreme pose (neck, head, upper arms at their servo limits),
    spine and chest limited to 5 degrees: us per iteration with and without the limits."""
    from puppet.rig import builtin

    rig = builtin()
    o = rig.solver_options
    model = FastModel(rig.V, rig.F, rig.W, clusters=o.clusters, extra_weights=o.extra_weights, energy=o.energy)
    base = rig.pattern()
    sk = rig.skeleton
    five = np.radians(5.0)
    limits = []
    for name in ("spine", "chest"):
        j = sk.index(name)
        d = sk.tails[j] - sk.heads[j]
        limits.append((j, int(sk.parents[j]), tuple(float(x) for x in d / np.linalg.norm(d)), five, -five, five))
    limited = Pattern(full=base.full, relative=base.relative, positional=base.positional, limits=tuple(limits))
    angles = np.zeros(len(rig.servo_map))
    for k, servo in enumerate(rig.servo_map.servos):
        if servo.joint in ("neck", "head"):
            angles[k] = servo.limits[1]
        elif servo.joint.startswith("upperarm"):
            angles[k] = servo.limits[1] if servo.sign > 0 else servo.limits[0]
    out = {}
    for name, pattern in (("plain", base), ("limits", limited)):
        solver = model.solver(pattern)
        values = pattern.values()
        times = []
        T = model.rest_T()
        for f in range(frames):
            rig.fill_values(angles * (0.9 + 0.1 * np.sin(f / 7)), values)
            t0 = cpu_ns()
            solver.solve(values, T, iterations=10)
            times.append((cpu_ns() - t0) / 10 / 1e3)
        out[f"{name}_us_per_iter"] = statistics.median(times[20:])
        out[f"{name}_active"] = solver.active_limits if pattern.limits else 0
    return out


def switch_case():
    """The built-in character: refactor time of the dropout pattern (the neck made free), the
    cached switch, and the largest per-frame vertex jump at both switches (still puppet, neck
    servo silent 500 ms, answering 26 degrees away), blended (6 frames) and not."""
    from puppet.bus import Reading
    from puppet.fast.live_solve import LiveSolve
    from puppet.loop import Pipeline
    from puppet.rig import builtin
    from puppet.rig.solve_options import SolveExtras

    rig = builtin()
    rig.extras = SolveExtras(on_dropout="free")
    neck = rig.skeleton.names.index("neck")
    with Pipeline(rig, render=False) as pipeline:
        model = pipeline.model
        refactor = []
        for _ in range(7):  # a fresh LiveSolve each time: the neck's pattern factored anew
            live = LiveSolve(model, rig.pattern, contact_targets=rig.contact_targets())
            live._state(frozenset({neck}))
            refactor.append(live.factor_ms[frozenset({neck})])
        T = model.rest_T()
        rot = np.tile(np.eye(3), (rig.skeleton.bone_count, 1, 1))
        pose = rig.skeleton.rest_pose()
        cached = []
        live.solve(frozenset(), rot, pose, T, 8)
        for _ in range(50):  # a cached switch each way: the pattern lookup and the warm start
            t0 = cpu_ns()
            live._switch_to(live._state(frozenset({neck}) if not live.free_bones else frozenset()),
                            frozenset({neck}) if not live.free_bones else frozenset(), T)
            cached.append((cpu_ns() - t0) / 1e6)
    ids = np.array([s.id for s in rig.servo_map.servos])
    from puppet.demo import Performance

    perf = Performance(rig)
    pose = np.array([perf.position(i, 0.0) for i in ids]).round().astype(np.int32)  # a held stance
    jumps = {}
    for blend in (6, 1):
        rig.extras = SolveExtras(on_dropout="free", blend_frames=blend)
        with Pipeline(rig, render=False) as pipeline:
            M = pipeline.model.lbs_matrix()
            prev, steps = None, []
            for f in range(80):
                ok = np.ones(len(ids), bool)
                ticks = pose.copy()
                if 20 <= f < 50:
                    ok[0] = False
                if f >= 50:
                    ticks[0] += 300
                pipeline.solve(Reading(int(f / 60 * 1e9), ids, ticks, ok))
                Vd = M @ pipeline.T
                steps.append(0.0 if prev is None else float(np.linalg.norm(Vd - prev, axis=1).max()))
                prev = Vd
        jumps[blend] = (max(steps[29:37]), max(steps[50:58]))
    rig.extras = SolveExtras()
    return {
        "m": model.m,
        "r": model.r,
        "refactor_ms": statistics.median(refactor),
        "cached_switch_ms": statistics.median(cached),
        "jump_to_free": jumps[6][0],
        "jump_to_sensed": jumps[6][1],
        "jump_to_free_unblended": jumps[1][0],
        "jump_to_sensed_unblended": jumps[1][1],
        "diag": float(np.linalg.norm(rig.V.max(0) - rig.V.min(0))),
    }


class NumpyStage:
    """The solve stage's forward kinematics and value filling as puppet had them before the native
    kernel (the per-bone NumPy loops of Skeleton.joint_rotations / pose_from_rotations and the
    per-bone value copies): the "before" of stage_case, kept here as the baseline only."""

    def __init__(self, skeleton, pattern):
        sk = skeleton
        axes = [sk.frames[j.bone] @ np.asarray(j.axes, float).reshape(-1, 3).T for j in sk.joints]
        stacked = np.concatenate([a.T for a in axes])
        self.dofs = np.concatenate([np.asarray(j.dofs, np.int64) for j in sk.joints])
        self.ranges, offset = [], 0
        for j in sk.joints:
            self.ranges.append((j.bone, offset, offset + len(j.dofs)))
            offset += len(j.dofs)
        self.outer = stacked[:, :, None] * stacked[:, None, :]
        self.i_minus_outer = np.eye(3) - self.outer
        self.cross = np.zeros((len(stacked), 3, 3))
        x, y, z = stacked.T
        self.cross[:, 0, 1], self.cross[:, 0, 2], self.cross[:, 1, 2] = -z, y, -x
        self.cross[:, 1, 0], self.cross[:, 2, 0], self.cross[:, 2, 1] = z, -y, x
        k = len(self.dofs)
        self.angle, self.cos, self.sin = np.empty(k), np.empty(k), np.empty(k)
        self.axis_rot, self.tmp = np.empty((k, 3, 3)), np.empty((k, 3, 3))
        self.mat, self.va, self.vb = np.empty((3, 3)), np.empty(3), np.empty(3)
        self.rot = np.tile(np.eye(3), (sk.bone_count, 1, 1))
        self.parents, self.heads = [int(p) for p in sk.parents], sk.heads
        self.full = list(pattern.full)
        self.children = [c for c, _, _ in pattern.relative]

    def joint_rotations(self, angles):
        np.take(angles, self.dofs, out=self.angle)
        np.cos(self.angle, out=self.cos)
        np.sin(self.angle, out=self.sin)
        np.multiply(self.i_minus_outer, self.cos[:, None, None], out=self.axis_rot)
        self.axis_rot += self.outer
        np.multiply(self.cross, self.sin[:, None, None], out=self.tmp)
        self.axis_rot += self.tmp
        rot, a = self.rot, self.axis_rot
        for bone, lo, hi in self.ranges:
            if hi - lo == 1:
                rot[bone] = a[lo]
            elif hi - lo == 2:
                np.matmul(a[lo], a[lo + 1], out=rot[bone])
            else:
                np.matmul(a[lo], a[lo + 1], out=self.mat)
                np.matmul(self.mat, a[lo + 2], out=rot[bone])
        return rot

    def pose_from_rotations(self, rot, out):
        offset, moved = self.va, self.vb
        for i, p in enumerate(self.parents):
            r, pivot = rot[i], self.heads[i]
            np.matmul(r, pivot, out=offset)
            np.subtract(pivot, offset, out=offset)
            if p < 0:
                out[i, :, :3] = r
                out[i, :, 3] = offset
            else:
                np.matmul(out[p, :, :3], r, out=out[i, :, :3])
                np.matmul(out[p, :, :3], offset, out=moved)
                np.add(moved, out[p, :, 3], out=out[i, :, 3])
        return out

    def fill(self, values, rot, pose):
        for i, j in enumerate(self.full):
            values.full[i] = pose[j].T
        for i, j in enumerate(self.children):
            values.relative[i] = rot[j]


def stage_case(frames):
    """The per-frame solve stage on the built-in critter against its iterations alone, in one run.

    Stage: ticks -> servo_map.angles -> forward kinematics (joint rotations, bone poses) ->
    constraint values -> one 8-iteration solve (accelerated, warm-started: the loop's default).
    Iterations alone: 8 x the per-iteration time of a 100-iteration call. "after" is the
    project's path (native FK, PoseFill); "before" the same with NumpyStage's per-bone loops.
    Each path warm-starts its own T (and solver) frame to frame over the demo's motion; the cases
    take turns in blocks of 20 frames (shared machine noise); figures are medians over the frames.
    Also: a solve call of 0 and of 8 iterations alone, each on its own solver with this frame's
    values (the fixed cost per call; and 0 iterations at a held pose, which keeps the relative
    rows' factor), and the loop's own Pipeline.solve (render=False: adds dropout bookkeeping and
    stage statistics)."""
    from puppet.demo import Performance
    from puppet.fast.pattern import PoseFill
    from puppet.loop import Pipeline
    from puppet.reading import Reading
    from puppet.rig import builtin

    rig = builtin()
    sk, smap = rig.skeleton, rig.servo_map
    with Pipeline(rig, render=False, iterations=8) as pipeline:
        model = pipeline.model
        pattern = rig.pattern()
        perf = Performance(rig)
        ids = np.array([s.id for s in smap.servos])
        n = frames + 20
        ticks = [np.array([perf.position(i, f / 60) for i in ids]).round().astype(np.int32) for f in range(n)]
        ok = np.ones(len(ids), bool)
        b = sk.bone_count
        paths = {}
        for name in ("after", "before"):
            values = pattern.values()
            rig.fill_values(smap.angles(ticks[0]), values)  # pins and contacts: constant per rig
            paths[name] = {"values": values, "T": model.rest_T(), "angles": np.empty(len(ids)),
                           "rot": np.empty((b, 3, 3)), "pose": np.empty((b, 3, 4))}
        fill, old = PoseFill(pattern), NumpyStage(sk, pattern)
        T100, Tfix, T0 = model.rest_T(), model.rest_T(), model.rest_T()
        # One solver per chain, as in the loop: a solver's first local step is free when it is
        # handed back the T it returned last (fast_solver.h), which alternating chains would spoil.
        solvers = {k: model.solver(pattern) for k in ("after", "before", "fixed", "zero", "long")}
        rig.fill_values(smap.angles(ticks[0]), paths["after"]["values"])
        for key, T in (("after", paths["after"]["T"]), ("before", paths["before"]["T"]), ("fixed", Tfix),
                       ("zero", T0), ("long", T100)):
            solvers[key].solve(paths["after"]["values"], T, iterations=200)  # every chain starts converged

        def after(f):
            p = paths["after"]
            smap.angles(ticks[f], out=p["angles"])
            pose = sk.pose(p["angles"], p["pose"], rotations=p["rot"])  # rotations and poses, one call
            fill.fill(p["values"], p["rot"], pose)
            solvers["after"].solve(p["values"], p["T"], iterations=8)

        def before(f):
            p = paths["before"]
            smap.angles(ticks[f], out=p["angles"])
            rot = old.joint_rotations(p["angles"])
            pose = old.pose_from_rotations(rot, p["pose"])
            old.fill(p["values"], rot, pose)
            solvers["before"].solve(p["values"], p["T"], iterations=8)

        def fk_after(f):
            sk.pose(paths["after"]["angles"], paths["after"]["pose"], rotations=paths["after"]["rot"])
            fill.fill(paths["after"]["values"], paths["after"]["rot"], paths["after"]["pose"])

        def fk_before(f):
            old.fill(paths["before"]["values"], old.joint_rotations(paths["before"]["angles"]),
                     old.pose_from_rotations(old.rot, paths["before"]["pose"]))

        # The solve calls alone get this frame's values, filled before the clock starts.
        frame_values = {k: pattern.values() for k in ("call_0", "call_8", "call_100")}
        for v in frame_values.values():
            v.positional[:], v.contact[:] = paths["after"]["values"].positional, paths["after"]["values"].contact
        rot, pose = np.empty((b, 3, 3)), np.empty((b, 3, 4))

        def prepare(key, f):
            fill.fill(frame_values[key], rot, sk.pose(smap.angles(ticks[f]), pose, rotations=rot))

        held = frame_values["call_0"]
        timed = {  # name: (untimed preparation or None, the timed call)
            "stage_after": (None, after), "stage_before": (None, before),
            "fk_values_after": (None, fk_after), "fk_values_before": (None, fk_before),
            "angles": (None, lambda f: smap.angles(ticks[f], out=paths["after"]["angles"])),
            "call_8": (prepare, lambda f: solvers["fixed"].solve(frame_values["call_8"], Tfix, iterations=8)),
            "call_0": (prepare, lambda f: solvers["zero"].solve(frame_values["call_0"], T0, iterations=0)),
            "call_0_held": (None, lambda f: solvers["zero"].solve(held, T0, iterations=0)),
            "call_100": (prepare, lambda f: solvers["long"].solve(frame_values["call_100"], T100, iterations=100)),
            "pipeline": (None, lambda f: pipeline.solve(Reading(int(f / 60 * 1e9), ids, ticks[f], ok))),
        }
        times = {k: [] for k in timed}
        keys = list(timed)
        block = 20  # frames per block: each case runs a block at a time (its data warm in cache, as
        for b0 in range(0, n, block):  # in the loop), the cases' order rotating from block to block
            turn = b0 // block % len(keys)
            for k in keys[turn:] + keys[:turn]:
                setup, run = timed[k]
                for f in range(b0, min(b0 + block, n)):
                    if setup is not None:
                        setup(k, f)
                    t0 = cpu_ns()
                    run(f)
                    if f >= 20:
                        times[k].append((cpu_ns() - t0) / 1e3)
    med = {k: statistics.median(v) for k, v in times.items()}
    per_iter = med.pop("call_100") / 100
    peak = peak_gflops()
    iterations_alone = 8 * per_iter
    return {
        "frames": frames, "m": model.m, "r": model.r, "bones": b,
        "us_per_iter_100_call": per_iter, "iterations_alone_us": iterations_alone,
        "gflops": flops_per_iter(model) / per_iter / 1e3, "peak_gflops": peak,
        "load_1min": os.getloadavg()[0],
        **{f"{k}_us": v for k, v in med.items()},
        "call_8_over_iterations_alone_us": med["call_8"] - iterations_alone,
        "ratio_after": med["stage_after"] / iterations_alone,
        "ratio_before": med["stage_before"] / iterations_alone,
        "ratio_pipeline": med["pipeline"] / iterations_alone,
        "target_ratio": 1.3,
    }


def print_stage(st):
    print(f"per-frame solve stage, built-in critter (m={st['m']}, r={st['r']}, {st['bones']} bones), "
          f"median of {st['frames']} frames, us:")
    print(f"  {'':<34}{'before':>9}{'after':>9}{'x':>7}")
    print(f"  {'FK + constraint values':<34}{st['fk_values_before_us']:>9.1f}{st['fk_values_after_us']:>9.1f}"
          f"{st['fk_values_before_us'] / st['fk_values_after_us']:>7.1f}")
    print(f"  {'stage: angles, FK, values, 8 it':<34}{st['stage_before_us']:>9.1f}{st['stage_after_us']:>9.1f}"
          f"{st['stage_before_us'] / st['stage_after_us']:>7.2f}")
    print(f"  {'stage / iterations alone':<34}{st['ratio_before']:>9.2f}{st['ratio_after']:>9.2f}"
          f"   (target <= {st['target_ratio']})")
    print(f"  the critter's iteration (a call of 100): {st['us_per_iter_100_call']:.2f} us, {st['gflops']:.1f} GFLOP/s "
          f"= {100 * st['gflops'] / st['peak_gflops']:.0f} % of the measured peak {st['peak_gflops']:.1f}; "
          f"thread CPU time, load average {st['load_1min']:.2f}")
    print(f"  iterations alone 8 x {st['us_per_iter_100_call']:.2f} = {st['iterations_alone_us']:.1f}; one solve "
          f"call of 8 iterations {st['call_8_us']:.1f}, of 0 (the fixed cost per call) {st['call_0_us']:.1f} "
          f"(held pose {st['call_0_held_us']:.1f})")
    print(f"  servo_map.angles {st['angles_us']:.1f}; the loop's Pipeline.solve {st['pipeline_us']:.1f} "
          f"({st['ratio_pipeline']:.2f} x)")


NATIVE_ARCH_BUILD = Path(__file__).resolve().parents[1] / "build" / "native-arch"
"""Where a -march=native build of the module is looked for (see README, Developer loop)."""

CASES = [("m5_r50", 5, 0, 50), ("m24_r100", 24, 0, 100), ("m25_5b20x_r200", 5, 20, 200)]


def per_iter_cases(V, F, frames):
    """Per-iteration medians (plain, accelerated) of every case, for comparing two builds."""
    out = {}
    for name, bones, extra, r in CASES:
        diag = float(np.linalg.norm(V.max(0) - V.min(0)))
        W = bone_weights(V, bones)
        model = FastModel(V, F, W, clusters=r, extra_weights=extra, energy="spokes_and_rims", cache_dir=False)
        pins = tuple(int(np.argmax(W[:, j])) for j in range(bones))
        pattern = Pattern(positional=pins)
        solver = model.solver(pattern)
        axes = np.random.default_rng(1).normal(size=(len(pins), 3))
        out[name] = per_iter_us(solver, pattern.values(), V, pins, diag, axes, frames, model)
    return out


def compare_builds(V, F, frames, args):
    """This build against the -march=native one (if built): per-iteration medians of each case,
    the other build run in a subprocess on the same mesh right after this one."""
    import glob
    import subprocess
    import tempfile

    found = sorted(glob.glob(str(NATIVE_ARCH_BUILD / "_native*.so")))
    if not found:
        return None
    mine = per_iter_cases(V, F, frames)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "other.json"
        subprocess.run([sys.executable, __file__, "--module", found[0], "--per-iter-only", "--json", str(out),
                        "--frames", str(frames)], check=True)
        other = json.loads(out.read_text())
    return {"portable_simd": _native.simd, "native_arch_simd": other["native_simd"], "native_arch_module": found[0],
            "cases": {k: {"portable_us": mine[k], "native_arch_us": other["per_iter"][k]} for k in mine}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", required=True, help="write results here")
    ap.add_argument("--frames", type=int, default=200, help="timed frames per case (>= 200 for the record)")
    ap.add_argument("--quick", action="store_true", help="smaller sample counts (smoke run)")
    ap.add_argument("--module", help="use this build of puppet._native (a .so file)")
    ap.add_argument("--per-iter-only", action="store_true", help="only the per-iteration medians (build comparison)")
    ap.add_argument("--stage-only", action="store_true", help="only the per-frame solve stage case (stage_case)")
    args = ap.parse_args(argv)
    if args.stage_only:
        stage = stage_case(args.frames)
        print_stage(stage)
        with open(args.json, "w") as fh:
            json.dump({"native_simd": _native.simd, "frames": args.frames, "stage": stage}, fh, indent=2)
        return
    V, F = character()
    if args.per_iter_only:
        with open(args.json, "w") as fh:
            json.dump({"native_simd": _native.simd, "per_iter": per_iter_cases(V, F, args.frames)}, fh)
        return
    peak = peak_gflops()
    results = [run_case(name, V, F, b, x, r, args.frames, args.quick) for name, b, x, r in CASES]
    peak = max(peak, peak_gflops())  # probed before and after the cases: the better of the two
    for c in results:
        c["fraction_of_peak"] = c["gflops"] / peak
    header = (
        f"{'case':<16}{'n':>7}{'m':>4}{'r':>5}{'us/it':>8}{'GFLOP/s':>8}{'% peak':>7}{'us/it acc':>10}{'prec s':>8}"
        f"{'refac ms':>9}{'it plain':>9}{'it acc':>7}{'numpy us':>10}{'full ms':>9}{'x numpy':>9}{'x full':>9}"
    )
    print(f"native build: simd={_native.simd}; {len(V)} vertices, {len(F)} triangles; {args.frames} frames; "
          f"thread CPU time; peak {peak:.1f} GFLOP/s (float32 BLAS probe); load average {os.getloadavg()[0]:.2f}")
    print(header)
    for c in results:
        print(
            f"{c['name']:<16}{c['n']:>7}{c['m']:>4}{c['r']:>5}{c['us_per_iter']:>8.2f}{c['gflops']:>8.1f}"
            f"{100 * c['fraction_of_peak']:>7.0f}{c['us_per_iter_accel']:>10.2f}"
            f"{c['precompute_s']:>8.3f}{c['refactor_ms']:>9.3f}{c['iters_plain']:>9}{c['iters_accel']:>7}"
            f"{c['numpy_us_per_iter']:>10.1f}{c['full_arap_ms_per_iter']:>9.1f}"
            f"{c['numpy_us_per_iter'] / c['us_per_iter']:>9.0f}{c['full_arap_ms_per_iter'] * 1e3 / c['us_per_iter']:>9.0f}"
        )
    live = live_cases(V, F, args.frames, args.quick)
    print(f"\nm5_r50 again: no dynamics or limits (accelerated) {live['us_per_iter']:.2f} us/it, dynamics on {live['dynamics_us_per_iter']:.2f} "
          f"us/it (x{live['dynamics_us_per_iter'] / live['us_per_iter']:.2f})")
    print(f"  limits on (4 active 5-degree limits): {live['limits_us_per_iter']:.2f} us/it "
          f"(x{live['limits_us_per_iter'] / live['us_per_iter']:.2f}, {live['limits_active']} active)")
    blim = builtin_limits_case(args.frames)
    print(f"built-in character, extreme pose: {blim['plain_us_per_iter']:.2f} us/it, spine and chest limited "
          f"{blim['limits_us_per_iter']:.2f} us/it (+{blim['limits_us_per_iter'] - blim['plain_us_per_iter']:.2f}, "
          f"{blim['limits_active']} active)")
    tol = tol_case(frames=10 if args.quick else 30)
    print(f"tolerance stop vs fixed budgets, built-in character, {tol['frames']} warm-started frames at 30 fps "
          f"(largest vertex distance from the converged result, % of the bounding-box diagonal):")
    for key, t in tol["runs"].items():
        print(f"  {key:<10} iterations/frame mean {t['iters_mean']:6.1f} max {t['iters_max']:4d}   "
              f"error max {t['err_max_pct_of_diag']:.4f} % mean {t['err_mean_pct_of_diag']:.4f} %")
    print(f"  the stop test's cost, us/iteration without / with tol: accelerated {tol['us_per_iter_accel']:.2f} / "
          f"{tol['us_per_iter_accel_tol']:.2f}, plain {tol['us_per_iter_plain']:.2f} / {tol['us_per_iter_plain_tol']:.2f}")
    if "fixed_budget" in tol:
        target = tol["target"]
        print(f"  at tol={target:g} (meant: every vertex within {target:g} of the diagonal): tol path mean "
              f"{tol['tol_iters_mean']:.1f} max {tol['tol_iters_max']} iterations, error max "
              f"{tol['tol_err_max_pct_of_diag']:.4f} % ({'within' if tol['tol_within_target'] else 'NOT within'} "
              f"{100 * target:g} %); a fixed budget needs {tol['fixed_budget']} iterations for every frame "
              f"(per-frame need mean {tol['per_frame_need_mean']:.1f})")
        verdict = "<" if tol["tol_iters_mean"] < tol["fixed_budget"] else "NOT <"
        print(f"  verdict: tol path mean {tol['tol_iters_mean']:.1f} {verdict} fixed budget {tol['fixed_budget']} "
              f"(ratio {tol['tol_over_fixed']:.2f})")
    sw = switch_case()
    print(f"built-in character (m={sw['m']}, r={sw['r']}): dropout pattern switch: refactor "
          f"{sw['refactor_ms']:.2f} ms, cached {sw['cached_switch_ms']:.3f} ms; largest per-frame vertex jump "
          f"(of the {sw['diag']:.2f} diagonal) to free {sw['jump_to_free']:.4f} (unblended "
          f"{sw['jump_to_free_unblended']:.4f}), back to sensed {sw['jump_to_sensed']:.4f} (unblended "
          f"{sw['jump_to_sensed_unblended']:.4f})")
    stage = stage_case(args.frames)
    print_stage(stage)
    m5 = results[0]
    checks = [(f"m5_r50 iteration {m5['us_per_iter']:.2f} us <= 1.5", m5["us_per_iter"] <= 1.5),
              (f"at {100 * m5['fraction_of_peak']:.0f} % >= 55 % of peak", m5["fraction_of_peak"] >= 0.55),
              (f"critter iteration {stage['us_per_iter_100_call']:.2f} us <= 10", stage["us_per_iter_100_call"] <= 10),
              (f"stage {stage['ratio_after']:.2f} x its 8 iterations <= 1.3", stage["ratio_after"] <= 1.3)]
    print("targets (thread CPU time): " + "; ".join(f"{text} {'met' if ok else 'NOT met'}" for text, ok in checks))
    builds = compare_builds(V, F, args.frames, args)
    if builds is None:
        print(f"(no -march=native build in {NATIVE_ARCH_BUILD}: build comparison skipped)")
    else:
        print(f"builds, us/iteration: portable ({builds['portable_simd']} kernels) vs -march=native "
              f"({builds['native_arch_simd']}):")
        for name, c in builds["cases"].items():
            print(f"  {name:<16}{c['portable_us']:>8.2f}{c['native_arch_us']:>8.2f}"
                  f"   native/portable {c['native_arch_us'] / c['portable_us']:.3f}")
    with open(args.json, "w") as fh:
        json.dump({"native_simd": _native.simd, "frames": args.frames, "clock": "thread CPU time",
                   "peak_gflops": peak, "load_1min": os.getloadavg()[0], "cases": results, "live": live,
                   "tol": tol, "switch": sw, "builtin_limits": blim, "stage": stage, "builds": builds}, fh, indent=2)


if __name__ == "__main__":
    main()
