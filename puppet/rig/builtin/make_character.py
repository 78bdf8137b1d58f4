"""Build the built-in character "critter" reproducibly: signed distance fields, marching cubes,
bounded biharmonic weights. Writes ``critter.npz``, ``critter.toml`` (the demo's rig),
``critter_dynamics.toml`` (the same with secondary motion, ``[solver.dynamics]``) and
``critter_ax.toml`` (the same joints on Protocol 1.0 servos: AX-12A and MX-28) next to this file.

    python -m puppet.rig.builtin.make_character [--voxel 0.0105] [--out DIR]
    python -m puppet.rig.builtin.make_character --toml-only   # rewrite the .toml files only

Needs scikit-image (marching cubes) and libigl with tetgen (weights). Deterministic: the same
inputs give the same files. Model units: the critter stands about 1.3 units tall, +Y up,
facing +Z, feet on y = 0.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

# ---- skeleton: name, parent, head (pivot), tail ------------------------------------------------
BONES = [
    ("hips", None, (0.0, 0.42, 0.0), (0.0, 0.55, 0.0)),
    ("spine", "hips", (0.0, 0.55, 0.0), (0.0, 0.70, 0.0)),
    ("chest", "spine", (0.0, 0.70, 0.0), (0.0, 0.85, 0.0)),
    ("neck", "chest", (0.0, 0.85, 0.0), (0.0, 0.93, 0.0)),
    ("head", "neck", (0.0, 0.93, 0.0), (0.0, 1.13, 0.03)),
    ("ear_L", "head", (0.08, 1.12, 0.0), (0.15, 1.28, -0.01)),
    ("ear_R", "head", (-0.08, 1.12, 0.0), (-0.15, 1.28, -0.01)),
    ("upperarm_L", "chest", (0.14, 0.80, 0.0), (0.30, 0.64, 0.03)),
    ("forearm_L", "upperarm_L", (0.30, 0.64, 0.03), (0.38, 0.48, 0.09)),
    ("upperarm_R", "chest", (-0.14, 0.80, 0.0), (-0.30, 0.64, 0.03)),
    ("forearm_R", "upperarm_R", (-0.30, 0.64, 0.03), (-0.38, 0.48, 0.09)),
    ("thigh_L", "hips", (0.10, 0.42, 0.0), (0.12, 0.23, 0.02)),
    ("shin_L", "thigh_L", (0.12, 0.23, 0.02), (0.12, 0.06, 0.03)),
    ("thigh_R", "hips", (-0.10, 0.42, 0.0), (-0.12, 0.23, 0.02)),
    ("shin_R", "thigh_R", (-0.12, 0.23, 0.02), (-0.12, 0.06, 0.03)),
    ("tail1", "hips", (0.0, 0.45, -0.12), (0.0, 0.36, -0.32)),
    ("tail2", "tail1", (0.0, 0.36, -0.32), (0.0, 0.40, -0.50)),
    ("tail3", "tail2", (0.0, 0.40, -0.50), (0.0, 0.53, -0.61)),
]

FIXED = ["hips"]  # the hips are bolted to the puppet's stand

# id, model, joint, axis, order, sign, zero_ticks, limits_deg
SERVOS = [
    (1, "XL330-M288", "neck", "x", 1, 1, 2048, (-40, 40)),
    (2, "XL330-M288", "head", "y", 1, 1, 2050, (-70, 70)),
    (3, "XL330-M288", "head", "x", 2, -1, 2046, (-40, 40)),
    (4, "XL430-W250", "upperarm_L", "x", 1, 1, 2048, (-100, 100)),
    (5, "XL430-W250", "upperarm_L", "z", 2, 1, 2044, (-80, 80)),
    (6, "XL330-M288", "forearm_L", "x", 1, 1, 2052, (-100, 100)),
    (7, "XL430-W250", "upperarm_R", "x", 1, -1, 2048, (-100, 100)),
    (8, "XL430-W250", "upperarm_R", "z", 2, -1, 2051, (-80, 80)),
    (9, "XL330-M288", "forearm_R", "x", 1, -1, 2045, (-100, 100)),
    (10, "XM430-W350", "thigh_L", "x", 1, 1, 2048, (-90, 90)),
    (11, "XM430-W350", "thigh_L", "z", 2, 1, 2049, (-45, 45)),
    (12, "XL430-W250", "shin_L", "x", 1, 1, 2047, (-90, 90)),
    (13, "XM430-W350", "thigh_R", "x", 1, -1, 2048, (-90, 90)),
    (14, "XM430-W350", "thigh_R", "z", 2, -1, 2043, (-45, 45)),
    (15, "XL430-W250", "shin_R", "x", 1, -1, 2050, (-90, 90)),
]

# The Protocol 1.0 variant critter_ax.toml: the same joints, axes, signs and limits on a
# Bioloid-style bus: servos AX_IDS are AX-12A (1024 positions over 300°; zero ticks 510 + id, about
# the middle of 0..1023 and each its own), the others (the legs and the right forearm) MX-28
# (Protocol 1.0 firmware, 4096 per turn, critter.toml's zero ticks).
AX_IDS = range(1, 9)
AX_MODEL, MX_MODEL = "AX-12A", "MX-28"

SOLVER = {"clusters": 100, "extra_weights": 8, "energy": "spokes_and_rims"}
# Secondary motion ([solver.dynamics]) of the optional variant critter_dynamics.toml (same mesh and
# servos): the ears and tail lag behind the sensed bones and settle. One solver step per 60 Hz
# frame; a slower frame takes up to max_steps steps. critter.toml (the demo's rig) stays without.
DYNAMICS = {"density": 0.002, "damping": 0.9, "dt": 0.016667, "max_steps": 4}
PIN_POINT = (0.0, 0.53, -0.66)  # tail tip rests on the stand's post


# ---- signed distance fields ------------------------------------------------------------------
def sd_round_cone(p, a, b, ra, rb):
    """Distance to a capsule from a (radius ra) to b (radius rb), approximately exact."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.linalg.norm(p - closest, axis=-1) - (ra + (rb - ra) * t)


def sd_ellipsoid(p, c, r):
    """Approximate distance to an ellipsoid centred at c with radii r (Quilez's bound)."""
    q = (p - np.asarray(c, float)) / np.asarray(r, float)
    k0 = np.linalg.norm(q, axis=-1)
    k1 = np.linalg.norm(q / np.asarray(r, float), axis=-1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def smooth_union(d1, d2, k):
    h = np.clip(0.5 + 0.5 * (d2 - d1) / k, 0.0, 1.0)
    return d2 + (d1 - d2) * h - k * h * (1.0 - h)


def critter_sdf(p):
    """Signed distance (negative inside) of the critter at points p (..., 3)."""
    body = sd_ellipsoid(p, (0, 0.62, 0), (0.22, 0.28, 0.19))
    belly = sd_ellipsoid(p, (0, 0.55, 0.05), (0.19, 0.2, 0.17))
    d = smooth_union(body, belly, 0.05)
    d = smooth_union(d, sd_ellipsoid(p, (0, 1.03, 0.02), (0.18, 0.165, 0.16)), 0.06)   # head
    d = smooth_union(d, sd_ellipsoid(p, (0, 0.98, 0.15), (0.085, 0.065, 0.07)), 0.03)  # snout
    for s in (1, -1):
        d = smooth_union(d, sd_ellipsoid(p, (0.065 * s, 1.06, 0.155), (0.032, 0.036, 0.025)), 0.01)  # eyes
        d = smooth_union(d, sd_round_cone(p, (0.08 * s, 1.11, 0.0), (0.155 * s, 1.30, -0.01), 0.05, 0.03), 0.03)
        d = smooth_union(d, sd_round_cone(p, (0.13 * s, 0.80, 0.0), (0.30 * s, 0.64, 0.03), 0.06, 0.05), 0.04)
        d = smooth_union(d, sd_round_cone(p, (0.30 * s, 0.64, 0.03), (0.38 * s, 0.50, 0.09), 0.05, 0.045), 0.02)
        d = smooth_union(d, sd_ellipsoid(p, (0.39 * s, 0.46, 0.10), (0.065, 0.06, 0.065)), 0.02)  # paw
        d = smooth_union(d, sd_round_cone(p, (0.10 * s, 0.42, 0.0), (0.12 * s, 0.23, 0.02), 0.085, 0.065), 0.04)
        d = smooth_union(d, sd_round_cone(p, (0.12 * s, 0.23, 0.02), (0.12 * s, 0.08, 0.03), 0.065, 0.06), 0.02)
        d = smooth_union(d, sd_ellipsoid(p, (0.12 * s, 0.045, 0.07), (0.075, 0.045, 0.11)), 0.03)  # foot
    d = smooth_union(d, sd_round_cone(p, (0, 0.45, -0.10), (0, 0.36, -0.32), 0.07, 0.055), 0.05)
    d = smooth_union(d, sd_round_cone(p, (0, 0.36, -0.32), (0, 0.40, -0.50), 0.055, 0.045), 0.02)
    d = smooth_union(d, sd_round_cone(p, (0, 0.40, -0.50), (0, 0.55, -0.62), 0.045, 0.035), 0.02)
    return d


def surface(voxel: float):
    """Marching cubes of the SDF: (V (n,3) float64, F (f,3) int64), outward, one component."""
    from skimage.measure import marching_cubes
    import igl

    lo = np.array([-0.55, -0.05, -0.75])
    hi = np.array([0.55, 1.42, 0.35])
    shape = np.ceil((hi - lo) / voxel).astype(int) + 1
    axes = [lo[i] + voxel * np.arange(shape[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    values = np.empty(shape, np.float32)
    for i in range(shape[0]):  # slab by slab to bound memory
        values[i] = critter_sdf(grid[i])
    V, F, _, _ = marching_cubes(values, 0.0, spacing=(voxel,) * 3, allow_degenerate=False)
    V = V + lo
    # Keep the largest connected component and drop unreferenced vertices.
    _, labels = igl.facet_components(F.astype(np.int64))
    F = F[labels == np.bincount(labels).argmax()]
    used = np.unique(F)
    remap = np.full(len(V), -1, np.int64)
    remap[used] = np.arange(len(used))
    V, F = V[used], remap[F]
    # Outward orientation: positive signed volume.
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() < 0:
        F = F[:, ::-1]
    return np.ascontiguousarray(V), np.ascontiguousarray(F)


def skeleton_arrays():
    from puppet.rig.skeleton import frame_from_direction

    names = [b[0] for b in BONES]
    parents = np.array([-1 if b[1] is None else names.index(b[1]) for b in BONES], np.int64)
    heads = np.array([b[2] for b in BONES], float)
    tails = np.array([b[3] for b in BONES], float)
    frames = np.array([frame_from_direction(t - h) for h, t in zip(heads, tails)])
    return names, parents, heads, tails, frames


def rig_toml(pin_vertex: int, dynamics: bool = False, protocol1: bool = False) -> str:
    """The rig file's text; dynamics: the variant with secondary motion ([solver.dynamics]);
    protocol1: the variant on AX-12A and MX-28 servos (AX_IDS)."""
    title = ('# The built-in character "critter": written by make_character.py, do not edit by hand.'
             if not dynamics and not protocol1
             else '# The built-in character "critter" with secondary motion (ears and tail lag and settle):\n'
             '# written by make_character.py, do not edit by hand. Same mesh and servos as critter.toml.'
             if dynamics
             else f'# The built-in character "critter" on one Protocol 1.0 bus: servos {AX_IDS[0]}..{AX_IDS[-1]} '
             f'{AX_MODEL}, the others {MX_MODEL}:\n'
             '# written by make_character.py, do not edit by hand. Same mesh, joints and limits as critter.toml.')
    out = [title,
           'name = "critter"', 'mesh = "critter.npz"',
           f"fixed = [{', '.join(repr(f).replace(chr(39), chr(34)) for f in FIXED)}]", "",
           "[solver]", f"clusters = {SOLVER['clusters']}", f"extra_weights = {SOLVER['extra_weights']}",
           f'energy = "{SOLVER["energy"]}"', ""]
    if dynamics:
        out += ["[solver.dynamics]  # secondary motion: the ears and tail lag and settle",
                *(f"{k} = {v}" for k, v in DYNAMICS.items()), ""]
    for sid, model, joint, axis, order, sign, zero, (lo, hi) in SERVOS:
        if protocol1:
            model, zero = (AX_MODEL, 510 + sid) if sid in AX_IDS else (MX_MODEL, zero)
        out += ["[[servo]]", f"id = {sid}", f'model = "{model}"', f'joint = "{joint}"', f'axis = "{axis}"',
                f"order = {order}", f"sign = {sign}", "gear = 1.0", f"zero_ticks = {zero}",
                f"limits_deg = [{lo}, {hi}]", ""]
    out += ["[[pin]]  # tail tip", f"vertex = {pin_vertex}", ""]
    return "\n".join(out)


def write_toml(out: Path, pin_vertex: int) -> None:
    """Write critter.toml (the demo's rig), critter_dynamics.toml (the variant with secondary
    motion) and critter_ax.toml (the Protocol 1.0 variant) for the tail-tip pin vertex."""
    (out / "critter.toml").write_text(rig_toml(pin_vertex))
    (out / "critter_dynamics.toml").write_text(rig_toml(pin_vertex, dynamics=True))
    (out / "critter_ax.toml").write_text(rig_toml(pin_vertex, protocol1=True))


def toml_only(out: Path = HERE) -> None:
    """Rewrite the rig files from this script's tables, keeping critter.npz and its pin vertex."""
    import tomllib

    pin = tomllib.loads((out / "critter.toml").read_text())["pin"][0]["vertex"]
    write_toml(out, int(pin))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--voxel", type=float, default=0.0105, help="marching-cubes voxel size")
    parser.add_argument("--weight-voxel", type=float, default=0.02,
                        help="voxel size of the coarser volume the weights are solved on")
    parser.add_argument("--out", type=Path, default=HERE, help="output folder")
    parser.add_argument("--toml-only", action="store_true",
                        help="rewrite the .toml files only (keep critter.npz and its pin vertex)")
    args = parser.parse_args(argv)
    if args.toml_only:
        toml_only(args.out)
        print(f"wrote {args.out / 'critter.toml'}, {args.out / 'critter_dynamics.toml'} and "
              f"{args.out / 'critter_ax.toml'}")
        return
    from puppet.rig.bbw import bbw_tet, interpolate_in_tets
    from puppet.rig.weight_check import normalize_weights
    from puppet.rig.skeleton import Skeleton
    from puppet.rig.weight_check import check_weights

    t0 = time.perf_counter()
    V, F = surface(args.voxel)
    print(f"surface: {len(V)} vertices, {len(F)} triangles ({time.perf_counter() - t0:.1f} s)")
    names, parents, heads, tails, frames = skeleton_arrays()
    skeleton = Skeleton(tuple(names), parents, heads, tails, frames)
    # BBW on the full-resolution volume (~45k tet vertices) takes many minutes on 2 cores, so
    # the weights are solved on a tet mesh of a coarser marching-cubes surface of the same SDF
    # and interpolated barycentrically at the fine surface's vertices.
    t0 = time.perf_counter()
    Vc, Fc = surface(args.weight_voxel)
    TV, TT, W_tet = bbw_tet(Vc, Fc, skeleton)
    print(f"bbw: coarse surface {len(Vc)} vertices, tet mesh {len(TV)} vertices / {len(TT)} tets")
    W = normalize_weights(interpolate_in_tets(TV, TT, W_tet, V))
    report = check_weights(W, len(V), names)
    print(f"weights: {W.shape}, {report.summary()} ({time.perf_counter() - t0:.1f} s)")
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        args.out / "critter.npz", V=V.astype(np.float32), F=F.astype(np.int32),
        W=W.astype(np.float32), names=np.array(names), parents=parents, heads=heads, tails=tails,
        frames=frames)
    pin = int(np.argmin(np.linalg.norm(V - np.array(PIN_POINT), axis=1)))
    write_toml(args.out, pin)
    print(f"wrote {args.out / 'critter.npz'}, {args.out / 'critter.toml'}, {args.out / 'critter_dynamics.toml'} "
          f"and {args.out / 'critter_ax.toml'}")


if __name__ == "__main__":
    main()
