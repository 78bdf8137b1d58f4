"""A seamed, textured, transformed character built from code, as Blender exports one ("mare").

Model space is the glTF scene's world space (+Y up, +Z forward). The character is a capped tube
body along +Z with two leg tubes below it (three primitives of one mesh), under an armature node
that is moved, turned and scaled unevenly; the mesh node is a child of the armature node with
its own translation, rotation and uneven scale. Bone names follow Blender's conventions: dots,
``.L``/``.R`` and ``.001`` suffixes.

    hips (root) ─ spine ─ neck ─ head
               ├ tail ─ tail.001
               ├ thigh.L ─ shin.L
               └ thigh.R ─ shin.R

Seams: each tube ring repeats its first vertex at its end (u = 0 and u = 1: a UV seam) and each
cap has its own copies of its ring (a hard edge), as glTF exporters write them. Every primitive has
two UV sets (TEXCOORD_0, TEXCOORD_1) and vertex colours (COLOR_0); the body's material has an
embedded PNG texture on TEXCOORD_0, the legs' is plain.

Skinning follows Blender's exporter: positions are in the mesh node's local space and each
inverse bind matrix is ``inverse(joint world) @ mesh world``, so the rest pose puts every vertex
at ``mesh world @ position`` (``rest_vertices()``, model space).
"""

from __future__ import annotations

import io

import numpy as np
import pygltflib as g
from scipy.spatial.transform import Rotation

SIDES = 12

# The armature node and the mesh node (a child of the armature): translation, rotation
# (quaternion x, y, z, w), scale; glTF axes (+Y up).
ARMATURE_TRS = ((1.5, 0.3, 2.0), Rotation.from_euler("y", 25, degrees=True).as_quat(), (1.2, 1.0, 0.8))
MESH_TRS = ((0.1, -0.05, 0.2), Rotation.from_euler("x", 10, degrees=True).as_quat(), (1.0, 1.1, 0.9))

# name, parent, head (armature space), direction of the bone's local +Y
BONES = (
    ("hips", None, (0.0, 0.0, 0.0), (0, 0, 1)),
    ("spine", "hips", (0.0, 0.0, 0.5), (0, 0, 1)),
    ("neck", "spine", (0.0, 0.0, 1.0), (0, 0, 1)),
    ("head", "neck", (0.0, 0.0, 1.4), (0, 0, 1)),
    ("tail", "hips", (0.0, 0.0, -0.1), (0, 0, -1)),
    ("tail.001", "tail", (0.0, 0.0, -0.45), (0, 0, -1)),
    ("thigh.L", "hips", (0.2, 0.0, 0.25), (0, -1, 0)),
    ("shin.L", "thigh.L", (0.2, -0.35, 0.25), (0, -1, 0)),
    ("thigh.R", "hips", (-0.2, 0.0, 0.25), (0, -1, 0)),
    ("shin.R", "thigh.R", (-0.2, -0.35, 0.25), (0, -1, 0)),
)
NAMES = tuple(b[0] for b in BONES)

# The servos of its rig: joint -> (id, axis); the solve fills in the other joints.
SERVOS = {"spine": (1, "x"), "neck": (2, "z"), "tail": (3, "x"), "thigh.L": (4, "x"), "thigh.R": (5, "z")}


def trs_matrix(trs) -> np.ndarray:
    """(4, 4) T @ R @ S of a (translation, quaternion xyzw, scale) triple."""
    t, q, s = trs
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix() * np.asarray(s, float)[None, :]
    m[:3, 3] = t
    return m


def bone_frame(direction) -> np.ndarray:
    """(3, 3) rest frame (columns = local x, y, z): y along the bone, x towards +X where possible."""
    y = np.asarray(direction, float)
    x = np.array([1.0, 0.0, 0.0]) - y[0] * y
    x /= np.linalg.norm(x)
    return np.column_stack([x, y, np.cross(x, y)])


def _tube(start, end, rings, radius):
    """A capped tube from ``start`` to ``end`` (3-vectors): (V, F, UV0, UV1) with a UV seam
    (each ring repeats its first vertex with u = 1) and caps with their own ring copies."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = (end - start) / np.linalg.norm(end - start)
    side = np.cross(axis, [0.0, 1.0, 0.0] if abs(axis[1]) < 0.9 else [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    other = np.cross(axis, side)
    cols = SIDES + 1
    V, UV = [], []
    for i, t in enumerate(np.linspace(0.0, 1.0, rings)):
        for j in range(cols):
            a = 2 * np.pi * j / SIDES
            V.append(start + (end - start) * t + radius * (np.cos(a) * side + np.sin(a) * other))
            UV.append((j / SIDES, t))
    F = []
    for i in range(rings - 1):
        for j in range(SIDES):
            a, b = i * cols + j, i * cols + j + 1
            F += [[a, a + cols, b], [b, a + cols, b + cols]]
    for ring_index, centre_point in ((0, start), (rings - 1, end)):
        ring = []
        for j in range(SIDES):
            a = 2 * np.pi * j / SIDES
            V.append(V[ring_index * cols + j])
            UV.append((0.5 + 0.25 * np.cos(a), 0.5 + 0.25 * np.sin(a)))
            ring.append(len(V) - 1)
        V.append(centre_point)
        UV.append((0.5, 0.5))
        centre = len(V) - 1
        for j in range(SIDES):
            tri = [centre, ring[j], ring[(j + 1) % SIDES]]
            F.append(tri if ring_index == 0 else tri[::-1])
    V, F, UV = np.array(V), np.array(F, np.int64), np.array(UV)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    if np.einsum("ij,ij->i", a - V.mean(0), np.cross(b - a, c - a)).sum() < 0:  # outward
        F = F[:, ::-1]
    UV1 = np.column_stack([UV[:, 1], UV[:, 0]])  # a second set: the first one transposed
    return V, F, UV, UV1


def _normals(V, F):
    N = np.zeros_like(V)
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    for c in range(3):
        np.add.at(N, F[:, c], cross)
    return N / np.linalg.norm(N, axis=1, keepdims=True)


def _weights(coordinate, centres, bones):
    """(n, len(NAMES)) weights: hat functions of one coordinate around each bone's centre,
    at most two per vertex."""
    W = np.zeros((len(coordinate), len(NAMES)))
    spacing = np.abs(np.diff(centres)).min()
    for c, name in zip(centres, bones):
        W[:, NAMES.index(name)] = np.clip(1.0 - np.abs(coordinate - c) / spacing, 0.0, None)
    nearest = np.argmin(np.abs(coordinate[:, None] - np.asarray(centres)[None, :]), axis=1)
    empty = W.sum(1) == 0
    W[np.flatnonzero(empty), [NAMES.index(bones[k]) for k in nearest[empty]]] = 1.0
    return W / W.sum(1, keepdims=True)


def primitives():
    """[(V (n, 3), F (f, 3), W (n, bones), UV0, UV1)] in armature space, rest pose."""
    body_V, body_F, uv0, uv1 = _tube((0, 0, -0.8), (0, 0, 1.8), 27, 0.25)
    body_W = _weights(body_V[:, 2], [-0.6, -0.25, 0.15, 0.7, 1.2, 1.6],
                      ["tail.001", "tail", "hips", "spine", "neck", "head"])
    prims = [(body_V, body_F, body_W, uv0, uv1)]
    for side, x in (("L", 0.2), ("R", -0.2)):
        V, F, a, b = _tube((x, -0.05, 0.25), (x, -0.7, 0.25), 9, 0.07)
        W = _weights(V[:, 1], [-0.15, -0.55], [f"thigh.{side}", f"shin.{side}"])
        prims.append((V, F, W, a, b))
    return prims


def armature_world() -> np.ndarray:
    return trs_matrix(ARMATURE_TRS)


def mesh_world() -> np.ndarray:
    """(4, 4) the mesh node's world transform (armature node @ mesh node)."""
    return armature_world() @ trs_matrix(MESH_TRS)


def rest_vertices() -> np.ndarray:
    """(n, 3) model-space (glTF world) rest positions of every file vertex, primitives in order."""
    A = armature_world()
    return np.concatenate([V @ A[:3, :3].T + A[:3, 3] for V, *_ in primitives()])


def _texture_png() -> bytes:
    from PIL import Image

    rng = np.random.default_rng(3)
    image = Image.fromarray(rng.integers(0, 255, (8, 8, 3), dtype=np.uint8), "RGB")
    out = io.BytesIO()
    image.save(out, format="PNG")
    return out.getvalue()


def build():
    """(GLTF2 document, binary blob) of the character."""
    blob = bytearray()
    views, accessors = [], []

    def view(data: bytes, target=None) -> int:
        while len(blob) % 4:
            blob.append(0)
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        return len(views) - 1

    def accessor(array, component, kind, target=None, minmax=False):
        array = np.ascontiguousarray(array)
        kw = {"min": array.min(0).tolist(), "max": array.max(0).tolist()} if minmax else {}
        accessors.append(g.Accessor(bufferView=view(array.tobytes(), target), componentType=component,
                                    count=len(array), type=kind, **kw))
        return len(accessors) - 1

    A, M = armature_world(), mesh_world()
    world = {}
    nodes = [g.Node(name="Armature", translation=list(ARMATURE_TRS[0]), rotation=list(ARMATURE_TRS[1]),
                    scale=list(ARMATURE_TRS[2]), children=[])]
    node_of = {}
    for name, parent, head, direction in BONES:
        local_in_armature = np.eye(4)
        local_in_armature[:3, :3] = bone_frame(direction)
        local_in_armature[:3, 3] = head
        world[name] = A @ local_in_armature
        parent_world = A if parent is None else world[parent]
        local = np.linalg.inv(parent_world) @ world[name]
        nodes.append(g.Node(name=name, translation=local[:3, 3].tolist(),
                            rotation=Rotation.from_matrix(local[:3, :3]).as_quat().tolist(), children=[]))
        node_of[name] = len(nodes) - 1
        (nodes[0] if parent is None else nodes[node_of[parent]]).children.append(node_of[name])

    to_mesh_local = np.linalg.inv(M) @ A  # armature space -> the mesh node's local space
    prims = []
    for k, (V, F, W, uv0, uv1) in enumerate(primitives()):
        local = V @ to_mesh_local[:3, :3].T + to_mesh_local[:3, 3]
        normals = _normals(V, F) @ np.linalg.inv(to_mesh_local[:3, :3])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        order = np.argsort(-W, axis=1, kind="stable")[:, :4]
        weights = np.take_along_axis(W, order, axis=1)
        attributes = g.Attributes(
            POSITION=accessor(local.astype(np.float32), g.FLOAT, g.VEC3, minmax=True),
            NORMAL=accessor(normals.astype(np.float32), g.FLOAT, g.VEC3),
            TEXCOORD_0=accessor(uv0.astype(np.float32), g.FLOAT, g.VEC2),
            TEXCOORD_1=accessor(uv1.astype(np.float32), g.FLOAT, g.VEC2),
            COLOR_0=accessor(np.column_stack([uv0, np.full(len(uv0), 0.5), np.ones(len(uv0))])
                             .astype(np.float32), g.FLOAT, g.VEC4),
            JOINTS_0=accessor(np.where(weights > 0, order, 0).astype(np.uint16), g.UNSIGNED_SHORT, g.VEC4),
            WEIGHTS_0=accessor(weights.astype(np.float32), g.FLOAT, g.VEC4))
        prims.append(g.Primitive(attributes=attributes, material=0 if k == 0 else 1,
                                 indices=accessor(F.reshape(-1).astype(np.uint32), g.UNSIGNED_INT,
                                                  g.SCALAR)))
    image_view = view(_texture_png())
    ibm = [(np.linalg.inv(world[name]) @ M).T.reshape(-1) for name in NAMES]  # column-major
    skin = g.Skin(name="Armature", joints=[node_of[n] for n in NAMES],
                  inverseBindMatrices=accessor(np.array(ibm, np.float32), g.FLOAT, g.MAT4))
    nodes.append(g.Node(name="mare", mesh=0, skin=0, translation=list(MESH_TRS[0]),
                        rotation=list(MESH_TRS[1]), scale=list(MESH_TRS[2])))
    nodes[0].children.append(len(nodes) - 1)
    materials = [
        g.Material(name="coat", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorTexture=g.TextureInfo(index=0, texCoord=0), metallicFactor=0.0)),
        g.Material(name="hoof", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=[0.2, 0.15, 0.1, 1.0], metallicFactor=0.0)),
    ]
    doc = g.GLTF2(asset=g.Asset(version="2.0", generator="puppet tests"), scene=0,
                  scenes=[g.Scene(nodes=[0])], nodes=nodes, skins=[skin],
                  meshes=[g.Mesh(name="mare", primitives=prims)], materials=materials,
                  textures=[g.Texture(source=0, sampler=0)], samplers=[g.Sampler()],
                  images=[g.Image(name="coat", bufferView=image_view, mimeType="image/png")],
                  accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))])
    return doc, bytes(blob)


def write_glb(path):
    """Write the character as a .glb at ``path``; returns the path."""
    doc, blob = build()
    doc.set_binary_blob(blob)
    doc.save_binary(str(path))
    return path


def rig_text(glb_name: str) -> str:
    """A rig file for the character (the mesh next to it): SERVOS, hips held still."""
    lines = [f'name = "mare"', f'mesh = "{glb_name}"', 'fixed = ["hips"]', "",
             "[solver]", "clusters = 30", "extra_weights = 0", 'energy = "spokes_and_rims"']
    for joint, (servo_id, axis) in SERVOS.items():
        lines += ["", "[[servo]]", f"id = {servo_id}", 'model = "XL330-M288"', f'joint = "{joint}"',
                  f'axis = "{axis}"', "zero_ticks = 2048", "limits_deg = [-60, 60]"]
    return "\n".join(lines) + "\n"
