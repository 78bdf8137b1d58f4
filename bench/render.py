"""Benchmark of puppet.render: frames per second (draw + read back) on this machine's renderer.

    python bench/render.py [--json FILE] [--frames 120] [--samples 4] [--extra 0] [--png FILE]

Cases: 640x480 and 1280x720; skinning on the GPU (vertex shader) and on the CPU (M @ T in NumPy,
uploaded each frame); antialiasing by MSAA (--samples, the Renderer's default 4), by FXAA (one
filter pass), or none. The character is puppet.rig.builtin() when it exists, else a procedural
one (~40k triangles, 17 bones, dense smooth weights: every vertex weighted by every bone, the
worst case for the shader). Each frame poses the bones anew (a new T), draws, and reads back
RGB into the renderer's preallocated image; the cases of one size take turns (a shared machine's
load falls on all alike). fps = frames / total time; also the median and best frame times.
Prints a table; writes
{"renderer", "character", "cases": [{"width", "height", "skinning", "fps", "antialias", ...}]}.
"""

import argparse
import json
import time

import numpy as np

from puppet.render import Renderer, create_context

TARGET_FPS_640 = 60.0

# Procedural character: bones as (parent, head, tail, tube radius); +Y up, facing +Z, ~1.7 tall.
BONES = [
    (None, (0, 0.95, 0), (0, 1.1, 0), 0.14),  # hips
    (0, (0, 1.1, 0), (0, 1.3, 0), 0.13),  # spine
    (1, (0, 1.3, 0), (0, 1.45, 0), 0.15),  # chest
    (2, (0, 1.45, 0), (0, 1.55, 0), 0.05),  # neck
    (3, (0, 1.55, 0), (0, 1.75, 0.02), 0.1),  # head
    (2, (0.17, 1.42, 0), (0.42, 1.4, 0), 0.05),  # upper arm L
    (5, (0.42, 1.4, 0), (0.66, 1.4, 0.02), 0.042),  # forearm L
    (6, (0.66, 1.4, 0.02), (0.76, 1.4, 0.03), 0.035),  # hand L
    (2, (-0.17, 1.42, 0), (-0.42, 1.4, 0), 0.05),  # upper arm R
    (8, (-0.42, 1.4, 0), (-0.66, 1.4, 0.02), 0.042),  # forearm R
    (9, (-0.66, 1.4, 0.02), (-0.76, 1.4, 0.03), 0.035),  # hand R
    (0, (0.1, 0.95, 0), (0.11, 0.52, 0.01), 0.07),  # thigh L
    (11, (0.11, 0.52, 0.01), (0.11, 0.08, 0), 0.055),  # shin L
    (12, (0.11, 0.08, 0), (0.11, 0.04, 0.16), 0.04),  # foot L
    (0, (-0.1, 0.95, 0), (-0.11, 0.52, 0.01), 0.07),  # thigh R
    (14, (-0.11, 0.52, 0.01), (-0.11, 0.08, 0), 0.055),  # shin R
    (15, (-0.11, 0.08, 0), (-0.11, 0.04, 0.16), 0.04),  # foot R
]


def _frame(axis: np.ndarray) -> np.ndarray:
    """(3, 3) orthonormal columns: two perpendiculars of axis, then axis."""
    axis = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    a = np.cross(axis, helper)
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(axis, a), axis], axis=1)


def procedural_character(rings: int = 44, sides: int = 28):
    """V (n, 3), F (f, 3), W (n, 17) dense smooth weights, bones (17, 2, 3), parents (17,)."""
    V_parts, F_parts, offset = [], [], 0
    for _, head, tail, radius in BONES:
        head, tail = np.array(head, float), np.array(tail, float)
        axis = tail - head
        length = np.linalg.norm(axis)
        frame = _frame(axis)
        # A capsule: tube rings plus hemispherical caps, as a latitude-longitude sphere stretched.
        lat = np.linspace(-np.pi / 2, np.pi / 2, rings)
        lon = np.linspace(0, 2 * np.pi, sides, endpoint=False)
        z = np.where(lat < 0, np.sin(lat) * radius, length + np.sin(lat) * radius)
        z = np.where(np.abs(lat) < 1e-9, length / 2, z)
        rho = np.cos(lat) * radius
        local = np.stack(
            [np.outer(rho, np.cos(lon)), np.outer(rho, np.sin(lon)), np.repeat(z[:, None], sides, 1)], axis=-1
        ).reshape(-1, 3)
        V_parts.append(head + local @ frame.T)
        i, j = np.meshgrid(np.arange(rings - 1), np.arange(sides), indexing="ij")
        a = i * sides + j
        b = i * sides + (j + 1) % sides
        quads = np.concatenate([np.stack([a, b, a + sides], -1), np.stack([b, b + sides, a + sides], -1)])
        F_parts.append(quads.reshape(-1, 3) + offset)
        offset += rings * sides
    V, F = np.concatenate(V_parts), np.concatenate(F_parts)
    bones = np.array([[head, tail] for _, head, tail, _ in BONES], dtype=float)
    # Dense smooth weights from the distance to each bone segment (every weight nonzero).
    d = np.empty((len(V), len(bones)))
    for k, (head, tail) in enumerate(bones):
        seg = tail - head
        t = np.clip((V - head) @ seg / (seg @ seg), 0, 1)
        d[:, k] = np.linalg.norm(V - (head + t[:, None] * seg), axis=1)
    W = 1.0 / (d + 0.01) ** 4
    W /= W.sum(axis=1, keepdims=True)
    parents = np.array([-1 if p is None else p for p, _, _, _ in BONES])
    return V, F, W, bones, parents


def builtin_character():
    """(V, F, W, bones (b, 2, 3), parents (b,), states, name, extra weights in its solver options)
    of puppet.rig.builtin() when it exists, else None."""
    try:
        import puppet.rig as rig
    except ImportError:
        return None
    make = getattr(rig, "builtin", None)
    if not callable(make):
        return None
    from puppet.rig.errors import RigError

    try:
        character = make()
    except (RigError, OSError) as err:  # the character's data files may not be built yet
        print(f"puppet.rig.builtin() unavailable ({err}); using the procedural character")
        return None
    skeleton = character.skeleton
    bones = np.stack([skeleton.heads, skeleton.tails], axis=1)
    kind_state = {"full": "sensed", "relative": "relative", "free": "free"}
    state_of = {name: kind_state.get(kind, "free") for kind, names in character.bone_kinds().items() for name in names}
    states = [state_of.get(name, "free") for name in skeleton.names]
    states[-1] = "fault"  # show every state in the demo picture
    V, F, W = (np.asarray(a) for a in (character.V, character.F, character.W))
    extra = int(getattr(getattr(character, "solver_options", None), "extra_weights", 0))
    return V, F, W, bones, np.asarray(skeleton.parents), states, "puppet.rig.builtin()", extra


def pose_T(bones: np.ndarray, parents: np.ndarray, m: int, phase: float) -> np.ndarray:
    """T (4m, 3) float32: every bone swings about its head (forward kinematics), extras identity."""
    A = np.tile(np.eye(4), (m, 1, 1))
    for k in range(len(bones)):
        angle = 0.3 * np.sin(phase + 0.7 * k)
        c, s = np.cos(angle), np.sin(angle)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        local = np.eye(4)
        local[:3, :3] = R
        local[:3, 3] = bones[k, 0] - R @ bones[k, 0]
        A[k] = (A[parents[k]] if parents[k] >= 0 else np.eye(4)) @ local
    return np.ascontiguousarray(A[:, :3, :].transpose(0, 2, 1).reshape(-1, 3), dtype=np.float32)


def add_extra_weights(V: np.ndarray, W: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """W with `count` compactly supported bumps appended (stand-ins for FAST's extra weights)."""
    if count == 0:
        return W
    rng = np.random.default_rng(seed)
    centers = V[rng.choice(len(V), count, replace=False)]
    radius = 0.25 * np.linalg.norm(V.max(0) - V.min(0))
    x = np.linalg.norm(V[:, None, :] - centers[None], axis=2) / radius
    bumps = np.where(x < 1, (1 - x) ** 3, 0.0)
    full = np.concatenate([W, bumps], axis=1)
    return full / full.sum(axis=1, keepdims=True)


def measure(renderers: list[Renderer], Ts: list[np.ndarray], frames: int, rounds: int = 6) -> np.ndarray:
    """Seconds per frame (len(renderers), frames) of draw(T), read back included.

    The cases take turns (rounds of frames // rounds frames each), so that load from other
    processes on a shared machine falls on all of them alike.
    """
    for renderer in renderers:
        for T in Ts[:5]:
            renderer.draw(T)
    per_round = max(1, frames // rounds)
    times = np.empty((len(renderers), per_round * rounds))
    for r in range(rounds):
        for i, renderer in enumerate(renderers):
            for k in range(r * per_round, (r + 1) * per_round):
                t0 = time.perf_counter()
                renderer.draw(Ts[k % len(Ts)])
                times[i, k] = time.perf_counter() - t0
    return times


def save_png(V, F, W_bones, bones, parents, states, ctx, path: str) -> None:
    """One 640x480 frame of the character posed by its bones only (extra weights need the
    solver to move sensibly), with the skeleton overlay colored by state."""
    import imageio.v3 as iio

    T = pose_T(bones, parents, W_bones.shape[1], 1.3)
    with Renderer(V, F, W_bones, context=ctx) as renderer:
        iio.imwrite(path, renderer.draw(T, bones=bones, bone_states=states))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", help="write the results to this JSON file")
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--samples", type=int, default=4, help="MSAA samples")
    parser.add_argument("--extra", type=int, default=None,
                        help="extra weights (default: the built-in rig's solver options; 0 for the procedural one)")
    parser.add_argument("--png", help="save one rendered frame of the character (with skeleton) here")
    args = parser.parse_args(argv)

    found = builtin_character()
    if found is not None:
        V, F, W, bones, parents, states, name, rig_extra = found
        W_bones = W
        args.extra = rig_extra if args.extra is None else args.extra
        if args.extra:
            from puppet.fast.model import FastModel  # the solver's weights: bones, then extras

            W = FastModel(V, F, W, clusters=50, extra_weights=args.extra, cache_dir=False).weights
    else:
        V, F, W, bones, parents = procedural_character()
        W_bones = W
        args.extra = args.extra or 0
        W = add_extra_weights(V, W, args.extra)
        states = ["sensed"] * 11 + ["relative"] * 2 + ["free"] * 3 + ["held"]
        name = f"procedural ({len(BONES)} bones)"
    name += f", {args.extra} extra weights" if args.extra else ""
    m = W.shape[1]
    Ts = [pose_T(bones, parents, m, phase) for phase in np.linspace(0, 2 * np.pi, 30)]

    ctx = create_context()
    gl_renderer = str(ctx.info["GL_RENDERER"])
    print(f"renderer: {gl_renderer}")
    print(f"character: {name}: {len(V)} vertices, {len(F)} triangles, {m} handles, "
          f"{np.count_nonzero(W) / len(V):.1f} weights per vertex; MSAA {args.samples}x")
    antialias = {f"msaa{args.samples}": dict(samples=args.samples), "fxaa": dict(samples=0, fxaa=True),
                 "none": dict(samples=0)}
    cases = []
    for width, height in ((640, 480), (1280, 720)):
        keys = [(aa, skinning) for aa in antialias for skinning in ("gpu", "cpu")]
        renderers = [
            Renderer(V, F, W, width=width, height=height, skinning=skinning, context=ctx, **antialias[aa])
            for aa, skinning in keys
        ]
        times = measure(renderers, Ts, args.frames)
        for (aa, skinning), renderer, seconds in zip(keys, renderers, times):
            renderer.release()
            cases.append({"width": width, "height": height, "skinning": skinning, "antialias": aa,
                          "fps": round(len(seconds) / seconds.sum(), 1),
                          "median_ms": round(float(np.median(seconds)) * 1e3, 2),
                          "best_ms": round(float(seconds.min()) * 1e3, 2)})

    print(f"{'size':>10} {'antialias':>9} {'skinning':>9} {'fps':>8} {'median ms':>10} {'best ms':>8}")
    for c in cases:
        print(f"{c['width']:>5}x{c['height']:<4} {c['antialias']:>9} {c['skinning']:>9} {c['fps']:>8.1f} "
              f"{c['median_ms']:>10.2f} {c['best_ms']:>8.2f}")
    for aa in antialias:
        gpu = next(c for c in cases if (c["width"], c["skinning"], c["antialias"]) == (640, "gpu", aa))
        cpu = next(c for c in cases if (c["width"], c["skinning"], c["antialias"]) == (640, "cpu", aa))
        verdict = "meets" if gpu["fps"] >= TARGET_FPS_640 else "misses"
        print(f"640x480 {aa}: GPU skinning {gpu['fps']:.1f} fps ({verdict} the {TARGET_FPS_640:.0f} fps target), "
              f"CPU skinning {cpu['fps']:.1f} fps, GPU / CPU = {gpu['fps'] / cpu['fps']:.2f}")
    if args.png:
        save_png(V, F, W_bones, bones, parents, states, ctx, args.png)
        print(f"picture: {args.png}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"renderer": gl_renderer, "character": name, "vertices": len(V), "triangles": len(F),
                       "handles": m, "cases": cases}, f, indent=2)
    ctx.release()


if __name__ == "__main__":
    main()
