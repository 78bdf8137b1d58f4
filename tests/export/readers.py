"""The tests' own readers of the exported formats, written from the formats' descriptions and
independent of puppet's writers (loaded by path: pytest runs with --import-mode=importlib).

BVH: the hierarchy and motion (``read_bvh``, which asserts the file's structure) and every
joint's world place per frame by forward kinematics of its channels (``forward_kinematics``,
``pivots``). PC2: ``read_pc2``. glTF (a pygltflib document): ``accessor`` data, node transforms
(``trs``, ``node_matrix``), world transforms through the node hierarchy (``worlds``) and the
joints' places per frame from the animation keys (``key_pivots``).
"""

import struct
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation


class Bvh(NamedTuple):
    """names: joints in file order; parents: each joint's parent index (-1: the root);
    offsets (b, 3); channels: each joint's channel names; end_sites: {joint name: offset};
    frame_time: seconds; motion (N, values): one row per frame."""

    names: list
    parents: list
    offsets: np.ndarray
    channels: list
    end_sites: dict
    frame_time: float
    motion: np.ndarray


def read_bvh(text: str) -> Bvh:
    """Parse a BVH file's text; an AssertionError names the first token out of place."""
    tokens = text.split()
    pos = 0
    names, parents, offsets, channels, end_sites, stack = [], [], [], [], {}, []

    def take():
        nonlocal pos
        pos += 1
        return tokens[pos - 1]

    assert take() == "HIERARCHY"
    while True:
        t = take()
        if t in ("ROOT", "JOINT"):
            names.append(take())
            parents.append(stack[-1] if stack else -1)
            assert take() == "{"
            assert take() == "OFFSET"
            offsets.append([float(take()) for _ in range(3)])
            assert take() == "CHANNELS"
            channels.append([take() for _ in range(int(take()))])
            stack.append(len(names) - 1)
        elif t == "End":
            assert take() == "Site" and take() == "{" and take() == "OFFSET"
            end_sites[names[stack[-1]]] = [float(take()) for _ in range(3)]
            assert take() == "}"
        elif t == "}":
            stack.pop()
        elif t == "MOTION":
            break
        else:
            raise AssertionError(f"unexpected token {t!r}")
    assert not stack
    assert take() == "Frames:"
    n = int(take())
    assert take() == "Frame" and take() == "Time:"
    frame_time = float(take())
    motion = np.array(tokens[pos:], float).reshape(n, -1) if n else np.zeros((0, 0))
    return Bvh(names, parents, np.array(offsets, float).reshape(-1, 3), channels, end_sites,
               frame_time, motion)


def forward_kinematics(bvh: Bvh, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """World positions (b, 3) and rotations (b, 3, 3) of every joint at one frame (parents come
    before their children in a BVH)."""
    b = len(bvh.names)
    pos, rot = np.zeros((b, 3)), np.zeros((b, 3, 3))
    values, col = bvh.motion[frame], 0
    for j in range(b):
        local_t, local_r = bvh.offsets[j].copy(), np.eye(3)
        for name in bvh.channels[j]:
            v = values[col]
            col += 1
            if name.endswith("position"):
                local_t["XYZ".index(name[0])] = v
            else:
                local_r = local_r @ Rotation.from_euler(name[0].lower(), v, degrees=True).as_matrix()
        p = bvh.parents[j]
        if p < 0:
            pos[j], rot[j] = local_t, local_r
        else:
            pos[j] = pos[p] + rot[p] @ local_t
            rot[j] = rot[p] @ local_r
    return pos, rot


def pivots(bvh: Bvh) -> np.ndarray:
    """(N, b, 3) world position of every joint in every frame."""
    return np.array([forward_kinematics(bvh, f)[0] for f in range(len(bvh.motion))]).reshape(
        len(bvh.motion), len(bvh.names), 3)


def read_pc2(path) -> tuple[dict, np.ndarray]:
    """(header {signature, version, num_points, start_frame, sample_rate, num_samples},
    (S, n, 3) float32 points) of a PC2 point cache."""
    data = open(path, "rb").read()
    sig, version, n, start, rate, s = struct.unpack_from("<12siiffi", data, 0)
    assert sig == b"POINTCACHE2\0" and version == 1
    header = dict(signature=sig, version=version, num_points=n, start_frame=start,
                  sample_rate=rate, num_samples=s)
    body = data[32:]
    assert len(body) == s * n * 12
    return header, np.frombuffer(body, dtype="<f4").reshape(s, n, 3)


GLTF_DTYPES = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
GLTF_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def accessor(gltf, index) -> np.ndarray:
    """The data of a glTF accessor in the binary chunk: (count,) or (count, width)."""
    a = gltf.accessors[index]
    view = gltf.bufferViews[a.bufferView]
    width = GLTF_WIDTHS[a.type]
    data = np.frombuffer(gltf.binary_blob(), np.dtype(GLTF_DTYPES[a.componentType]), count=a.count * width,
                         offset=view.byteOffset + (a.byteOffset or 0))
    return data.reshape(a.count, width) if width > 1 else data


def trs(translation, quaternion, scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(4, 4) T @ R @ S of a translation, a quaternion (x, y, z, w) and a scale."""
    M = np.eye(4)
    M[:3, :3] = Rotation.from_quat(quaternion).as_matrix() * np.asarray(scale, float)[None, :]
    M[:3, 3] = translation
    return M


def node_matrix(node) -> np.ndarray:
    """(4, 4) local transform of a glTF node (its matrix, or its TRS with glTF's defaults)."""
    if node.matrix:
        return np.array(node.matrix).reshape(4, 4).T
    return trs(node.translation or [0, 0, 0], node.rotation or [0, 0, 0, 1], node.scale or [1, 1, 1])


def worlds(gltf, locals_: dict) -> np.ndarray:
    """(k, 4, 4) world transform of every node of ``locals_`` ({node: local 4x4}; each node's
    ancestors among them), in node order, through the file's node hierarchy."""
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}
    out = {}

    def world(j):
        if j not in out:
            out[j] = locals_[j] if j not in parent else world(parent[j]) @ locals_[j]
        return out[j]

    return np.array([world(j) for j in sorted(locals_)])


def key_pivots(gltf, b: int) -> tuple[np.ndarray, list[int]]:
    """((N, b, 3) world position of joint nodes 0..b-1 in every frame of the first animation's
    translation and rotation keys, [key count of each sampler])."""
    anim = gltf.animations[0]
    keys = {(c.target.node, c.target.path): accessor(gltf, anim.samplers[c.sampler].output)
            for c in anim.channels}
    frames = len(keys[0, "translation"])
    out = np.array([worlds(gltf, {j: trs(keys[j, "translation"][f], keys[j, "rotation"][f]) for j in range(b)})
                    [:, :3, 3] for f in range(frames)]).reshape(frames, b, 3)
    return out, [len(accessor(gltf, s.input)) for s in anim.samplers]
