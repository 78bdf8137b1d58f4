"""A skinned glTF character built from code, as Blender would export it (shared by the rig tests).

"beast": a capped tube body along +Z (glTF forward), +Y up, with a leg tube below it (a second
primitive), under an "Armature" node that is not a joint. Joints, nested, Blender-style (each
bone's local +Y runs along the bone):

    hips (root) ─ spine ─ neck ─ head
               ├ tail base ─ tail tip          (a joint name with a space)
               └ leg.L ─ foot.L

``split=True`` writes the mesh the way glTF exporters do at UV seams: each ring of a tube
repeats its first vertex at its end (same position and weights, own normal and UV) and each
cap has its own ring copies; ``split=False`` writes the same surface with no copies, so that
welding the split file must give exactly the unsplit one.
"""

from __future__ import annotations

import numpy as np
import pygltflib as g
from scipy.spatial.transform import Rotation

SIDES = 10
ARMATURE_OFFSET = np.array([0.0, 0.6, 0.0])

# name, parent, head (model space), direction of the bone's local +Y
BONES = (
    ("hips", None, (0.0, 0.0, 0.0), (0, 0, 1)),
    ("spine", "hips", (0.0, 0.0, 0.5), (0, 0, 1)),
    ("neck", "spine", (0.0, 0.0, 1.0), (0, 0, 1)),
    ("head", "neck", (0.0, 0.0, 1.4), (0, 0, 1)),
    ("tail base", "hips", (0.0, 0.0, -0.1), (0, 0, -1)),
    ("tail tip", "tail base", (0.0, 0.0, -0.5), (0, 0, -1)),
    ("leg.L", "hips", (0.18, 0.0, 0.25), (0, -1, 0)),
    ("foot.L", "leg.L", (0.18, -0.35, 0.25), (0, -1, 0)),
)
NAMES = tuple(b[0] for b in BONES)


def bone_frame(direction) -> np.ndarray:
    """(3, 3) rest frame, columns = local x, y, z: y along the bone, x the character's left (+X)
    where possible (Blender's roll 0 for these bones)."""
    y = np.asarray(direction, float)
    x = np.array([1.0, 0.0, 0.0])
    x = x - (x @ y) * y
    x /= np.linalg.norm(x)
    return np.column_stack([x, y, np.cross(x, y)])


def _tube(z0, z1, rings, radius, center, axis, split):
    """A capped tube along ``axis`` ('z' or '-y') through center (x, y, z): (V, F, ring_ts)."""
    ts = np.linspace(0.0, 1.0, rings)
    cols = SIDES + 1 if split else SIDES
    angles = 2 * np.pi * np.arange(cols) / SIDES
    V = []
    for t in ts:
        along = z0 + (z1 - z0) * t
        for a in angles:
            c, s = radius * np.cos(a), radius * np.sin(a)
            if axis == "z":
                V.append([center[0] + c, center[1] + s, along])
            else:
                V.append([center[0] + c, along, center[2] + s])
    F = []
    for i in range(rings - 1):
        for j in range(SIDES):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            c, d = a + cols, b + cols
            F += [[a, c, b], [b, c, d]]
    # Caps: a centre vertex and, when split, the cap's own ring copies (a hard edge).
    for end, t in ((0, 0), (1, rings - 1)):
        ring = [t * cols + j for j in range(SIDES)]
        if split:
            ring = []
            for j in range(SIDES):
                V.append(V[t * cols + j])
                ring.append(len(V) - 1)
        along = z0 if end == 0 else z1
        V.append([center[0], center[1], along] if axis == "z" else [center[0], along, center[2]])
        centre = len(V) - 1
        for j in range(SIDES):
            tri = [centre, ring[j], ring[(j + 1) % SIDES]]  # wound like the sides
            F.append(tri if end == 0 else tri[::-1])
    V, F = np.array(V, float), np.array(F, np.int64)
    # Outward orientation: signed volume positive.
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    if np.einsum("ij,ij->i", a - V.mean(0), np.cross(b - a, c - a)).sum() < 0:
        F = F[:, ::-1]
    return V, F


def _hat_weights(coordinate, centers, columns, count):
    """(n, count) weights: hat functions of one coordinate around each bone centre."""
    W = np.zeros((len(coordinate), count))
    spacing = np.abs(np.diff(centers)).min()
    for c, col in zip(centers, columns):
        W[:, col] = np.clip(1.0 - np.abs(coordinate - c) / spacing, 0.0, None)
    top = np.argsort(-W, axis=1)[:, :2]  # at most two influences per vertex
    keep = np.zeros_like(W, bool)
    np.put_along_axis(keep, top, True, axis=1)
    W = np.where(keep, W, 0.0)
    W[W.sum(1) == 0, columns[np.argmin(np.abs(coordinate[W.sum(1) == 0, None] - centers), axis=1)]] = 1.0
    return W / W.sum(axis=1, keepdims=True)


def mesh(split: bool = True):
    """Primitives [(V (n, 3) float32, F (f, 3), W (n, bones))], model space (rest pose)."""
    index = {n: i for i, n in enumerate(NAMES)}
    body_V, body_F = _tube(-0.7, 1.8, 26, 0.25, (0.0, 0.0, 0.0), "z", split)
    body_cols = np.array([index[n] for n in ("tail tip", "tail base", "hips", "spine", "neck", "head")])
    body_W = _hat_weights(body_V[:, 2], np.array([-0.6, -0.3, 0.15, 0.7, 1.2, 1.6]), body_cols, len(NAMES))
    leg_V, leg_F = _tube(-0.05, -0.7, 8, 0.07, (0.18, 0.0, 0.25), "-y", split)
    leg_cols = np.array([index["leg.L"], index["foot.L"]])
    leg_W = _hat_weights(leg_V[:, 1], np.array([-0.15, -0.55]), leg_cols, len(NAMES))
    return [(body_V.astype(np.float32), body_F, body_W), (leg_V.astype(np.float32), leg_F, leg_W)]


def build(split: bool = True, *, skins: int = 1, ibm_override: dict | None = None,
          extra_joint: str | None = None):
    """(GLTF2 document, binary blob) of the character.

    skins: 2 adds a second skinned copy of the body with its own skin.
    ibm_override: {bone name: (4, 4) matrix} written instead of that joint's inverse bind matrix.
    extra_joint: the name of one more joint (child of head) that no vertex follows.
    """
    blob = bytearray()
    views, accessors = [], []

    def accessor(array: np.ndarray, component, kind, target=None, minmax=False):
        while len(blob) % 4:
            blob.append(0)
        data = np.ascontiguousarray(array).tobytes()
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        kw = {}
        if minmax:
            kw = {"min": array.min(0).tolist(), "max": array.max(0).tolist()}
        accessors.append(g.Accessor(bufferView=len(views) - 1, componentType=component,
                                    count=len(array), type=kind, **kw))
        return len(accessors) - 1

    bones = list(BONES) + ([(extra_joint, "head", (0.0, 0.0, 1.7), (0, 0, 1))] if extra_joint else [])
    names = [b[0] for b in bones]
    globals_ = {}
    for name, _, head, direction in bones:
        G = np.eye(4)
        G[:3, :3] = bone_frame(direction)
        G[:3, 3] = np.asarray(head) + ARMATURE_OFFSET
        globals_[name] = G
    armature = np.eye(4)
    armature[:3, 3] = ARMATURE_OFFSET
    nodes = [g.Node(name="Armature", translation=ARMATURE_OFFSET.tolist(), children=[])]
    node_of = {}
    for name, parent, _, _ in bones:
        parent_global = armature if parent is None else globals_[parent]
        local = np.linalg.inv(parent_global) @ globals_[name]
        quat = Rotation.from_matrix(local[:3, :3]).as_quat()  # x, y, z, w
        nodes.append(g.Node(name=name, translation=local[:3, 3].tolist(), rotation=quat.tolist(), children=[]))
        node_of[name] = len(nodes) - 1
        (nodes[0] if parent is None else nodes[node_of[parent]]).children.append(node_of[name])

    primitives = []
    for V, F, W in mesh(split):
        # Mesh positions are in bind space = model space here, offset by the armature.
        W_full = np.zeros((len(V), len(bones)))
        W_full[:, :W.shape[1]] = W
        order = np.argsort(-W_full, axis=1)[:, :4]
        joints = order.astype(np.uint16)
        weights = np.take_along_axis(W_full, order, axis=1).astype(np.float32)
        attributes = g.Attributes(
            POSITION=accessor((V + ARMATURE_OFFSET).astype(np.float32), g.FLOAT, g.VEC3, minmax=True),
            JOINTS_0=accessor(joints, g.UNSIGNED_SHORT, g.VEC4),
            WEIGHTS_0=accessor(weights, g.FLOAT, g.VEC4))
        primitives.append(g.Primitive(attributes=attributes,
                                      indices=accessor(F.reshape(-1).astype(np.uint32), g.UNSIGNED_INT, g.SCALAR)))
    ibm = []
    for name in names:
        m = np.linalg.inv(globals_[name])
        if ibm_override and name in ibm_override:
            m = np.asarray(ibm_override[name], float)
        ibm.append(m.T.reshape(-1))  # column-major
    skin_list = [g.Skin(name="Armature", joints=[node_of[n] for n in names],
                        inverseBindMatrices=accessor(np.array(ibm, np.float32), g.FLOAT, g.MAT4))]
    meshes = [g.Mesh(name="beast", primitives=primitives)]
    nodes.append(g.Node(name="beast", mesh=0, skin=0))
    scene_nodes = [0, len(nodes) - 1]
    if skins == 2:
        skin_list.append(g.Skin(name="Second", joints=[node_of[n] for n in names],
                                inverseBindMatrices=skin_list[0].inverseBindMatrices))
        meshes.append(g.Mesh(name="twin", primitives=primitives[:1]))
        nodes.append(g.Node(name="twin", mesh=1, skin=1))
        scene_nodes.append(len(nodes) - 1)
    doc = g.GLTF2(asset=g.Asset(version="2.0", generator="puppet tests"), scene=0,
                  scenes=[g.Scene(nodes=scene_nodes)], nodes=nodes, skins=skin_list, meshes=meshes,
                  accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))])
    return doc, bytes(blob)


def write_glb(path, split: bool = True, **kwargs):
    """Write the character as a .glb at ``path``; returns the path."""
    doc, blob = build(split, **kwargs)
    doc.set_binary_blob(blob)
    doc.save_binary(str(path))
    return path


def rest_vertices(split: bool = True) -> np.ndarray:
    """(n, 3) model-space rest positions of every file vertex, primitives in order."""
    return np.concatenate([V.astype(np.float64) + ARMATURE_OFFSET for V, _, _ in mesh(split)])


def enable_servos(text: str, servos: dict[str, dict]) -> str:
    """Uncomment the [[servo]] blocks that ``puppet rig init`` wrote for these joints and set
    their keys: ``servos`` is {joint name: {key: value}} (values as TOML text, e.g. '"z"')."""
    lines = text.splitlines()
    out, i = [], 0
    while i < len(lines):
        if lines[i] == "# [[servo]]":
            block = []
            while i < len(lines) and lines[i].startswith("# "):
                block.append(lines[i])
                i += 1
            joint_line = next(line for line in block if line.startswith("# joint = "))
            joint = joint_line.split("=", 1)[1].strip().strip('"')
            if joint in servos:
                keys = dict(servos[joint])
                block = [line[2:] for line in block]
                for k, line in enumerate(block):
                    key = line.split("=", 1)[0].strip()
                    if key in keys:
                        block[k] = f"{key} = {keys.pop(key)}"
                block += [f"{key} = {value}" for key, value in keys.items()]
            out += block
            continue
        out.append(lines[i])
        i += 1
    return "\n".join(out) + "\n"
