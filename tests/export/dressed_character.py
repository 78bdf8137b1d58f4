"""A skinned glTF character with a look and a place, as Blender exports one (export tests).

"pillar": a tube along the mesh's +Y with a UV seam (each ring repeats its first vertex at its
end: same position and weights, its own UV), and caps in a second primitive with its own copies
of the end rings (a hard edge) and a second, plain material.
Three joints along it (root, mid, top) under an "Armature" node that is not a joint; the mesh
node "pillar" is a child of "Armature"; a "Marker" empty is a child of the top joint's parent.
Armature and mesh nodes carry a translation, a rotation and a non-uniform scale (``moved``).

Attributes: POSITION, NORMAL, TEXCOORD_0 (the seam's u = 0 and u = 1), JOINTS_0/WEIGHTS_0, and
on the sides TEXCOORD_1 (a second set) and COLOR_0 (RGBA float). Material "skin" (the sides):
its base colour a 4x4 PNG texture read through TEXCOORD_0, embedded in a .glb, a file next to
a .gltf; material "cap": colour factors only.

Positions are in the mesh node's space; inverse bind matrices are inverse(joint world) times
the mesh node's world (Blender's way), so the rest pose is the bind pose and the model-frame
rest vertices are ``mesh_world() @ POSITION``.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pygltflib as g
from scipy.spatial.transform import Rotation

SIDES = 8
RINGS = 7
HEIGHT = 2.0
RADIUS = 0.3
JOINTS = (("root", None, 0.0), ("mid", "root", 0.7), ("top", "mid", 1.4))  # name, parent, y
NAMES = tuple(j[0] for j in JOINTS)
# (translation, rotation quaternion x y z w, scale) of the Armature node and of the mesh node
# (relative to the Armature node): moved, turned and squashed.
ARMATURE_TRS = ((1.5, 0.3, 2.0), tuple(Rotation.from_euler("xyz", [20, -35, 10], degrees=True).as_quat()),
                (1.2, 1.0, 0.8))
MESH_TRS = ((0.1, -0.2, 0.05), tuple(Rotation.from_euler("xyz", [0, 15, 0], degrees=True).as_quat()),
            (1.1, 0.9, 1.0))
IDENTITY_TRS = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (1.0, 1.0, 1.0))
IMAGE = "pillar_skin.png"


def trs_matrix(trs) -> np.ndarray:
    """(4, 4) T·R·S of (translation, quaternion xyzw, scale)."""
    t, q, s = trs
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix() * np.asarray(s, float)[None, :]
    m[:3, 3] = t
    return m


def _trs(moved, armature: bool):
    """The Armature's (or the mesh node's) TRS: ``moved`` True: ARMATURE_TRS / MESH_TRS; False:
    identity; or a (translation, quaternion, scale) of the Armature itself (mesh: MESH_TRS)."""
    if moved is True:
        return ARMATURE_TRS if armature else MESH_TRS
    if moved is False:
        return IDENTITY_TRS
    return moved if armature else MESH_TRS


def armature_world(moved=True) -> np.ndarray:
    return trs_matrix(_trs(moved, True))


def mesh_world(moved=True) -> np.ndarray:
    """(4, 4) world transform of the mesh node."""
    return armature_world(moved) @ trs_matrix(_trs(moved, False))


def _weights(V: np.ndarray) -> np.ndarray:
    """(n, 3) weights over NAMES: hat functions of the mesh-space height."""
    heads = np.array([y for _, _, y in JOINTS])
    W = np.clip(1.0 - np.abs(V[:, 1:2] - (heads + 0.35)[None, :]) / 0.7, 0.0, None)
    W[W.sum(1) == 0, 0] = 1.0
    return W / W.sum(1, keepdims=True)


def primitives():
    """The two primitives, mesh space, as dicts of V (n, 3) float32, F (f, 3) int64 (local
    indices), N (n, 3), uv0 (n, 2), uv1 (n, 2) or None, colours (n, 4) float32 or None, W (n, 3):
    "sides" (material 0: the textured skin; a UV seam: each ring repeats its first vertex) and
    "caps" (material 1: plain; each cap its own copies of the end rings, hard edged, centre
    vertices; no TEXCOORD_1 or COLOR_0)."""
    cols = SIDES + 1
    V, N, uv0 = [], [], []
    for i in range(RINGS):
        y = HEIGHT * i / (RINGS - 1)
        for j in range(cols):
            a = 2 * np.pi * j / SIDES
            V.append([RADIUS * np.cos(a), y, RADIUS * np.sin(a)])
            N.append([np.cos(a), 0.0, np.sin(a)])
            uv0.append([j / SIDES, 1.0 - i / (RINGS - 1)])
    F = []
    for i in range(RINGS - 1):
        for j in range(SIDES):
            a, b = i * cols + j, i * cols + j + 1
            c, d = a + cols, b + cols
            F += [[a, c, b], [b, c, d]]
    V, N, uv0 = np.array(V, np.float32), np.array(N, np.float32), np.array(uv0, np.float32)
    sides = {"V": V, "F": np.array(F, np.int64), "N": N, "uv0": uv0,
             "uv1": (0.25 + 0.5 * uv0[:, ::-1]).astype(np.float32),
             "colours": np.column_stack([0.5 + 0.5 * np.cos(3 * V[:, 1]), V[:, 1] / HEIGHT,
                                         0.5 + V[:, 0], np.ones(len(V))]).astype(np.float32)}
    cV, cN, cuv, cF = [], [], [], []
    for end in (0, 1):
        y = HEIGHT * end
        start = len(cV)
        for j in range(SIDES):
            a = 2 * np.pi * j / SIDES
            cV.append([RADIUS * np.cos(a), y, RADIUS * np.sin(a)])
            cuv.append([0.5 + 0.5 * np.cos(a), 0.5 + 0.5 * np.sin(a)])
        cV.append([0.0, y, 0.0])
        cuv.append([0.5, 0.5])
        cN += [[0.0, 1.0 if end else -1.0, 0.0]] * (SIDES + 1)
        centre = len(cV) - 1
        for j in range(SIDES):
            tri = [centre, start + (j + 1) % SIDES, start + j]
            cF.append(tri if end else tri[::-1])
    caps = {"V": np.array(cV, np.float32), "F": np.array(cF, np.int64), "N": np.array(cN, np.float32),
            "uv0": np.array(cuv, np.float32), "uv1": None, "colours": None}
    for prim in (sides, caps):
        prim["W"] = _weights(prim["V"])
    return [sides, caps]


def file_vertices() -> np.ndarray:
    """(n, 3) float32 mesh-space positions of every file vertex, primitives in order."""
    return np.concatenate([p["V"] for p in primitives()])


def png_bytes() -> bytes:
    """A 4x4 RGBA PNG checker."""
    from PIL import Image

    pixels = np.zeros((4, 4, 4), np.uint8)
    pixels[..., 3] = 255
    pixels[::2, ::2, 0] = 220
    pixels[1::2, 1::2, 0] = 220
    pixels[..., 1] = 90
    pixels[:, :2, 2] = 200
    out = io.BytesIO()
    Image.fromarray(pixels, "RGBA").save(out, format="PNG")
    return out.getvalue()


def build(path, *, moved=True, binary: bool | None = None, image_file: bool = True):
    """Write the character to ``path`` (.glb: the image embedded; .gltf: the buffer as a data
    uri and the image as ``IMAGE`` next to it, written unless ``image_file`` is False).
    moved: True (ARMATURE_TRS, MESH_TRS), False (no transforms) or the Armature's own
    (translation, quaternion, scale) with MESH_TRS. Returns the path."""
    path = Path(path)
    binary = path.suffix.lower() == ".glb" if binary is None else binary
    blob = bytearray()
    views, accessors = [], []

    def view(data: bytes, target=None) -> int:
        while len(blob) % 4:
            blob.append(0)
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        return len(views) - 1

    def accessor(array, component, kind, target=None, minmax=False) -> int:
        array = np.ascontiguousarray(array)
        kw = {}
        if minmax:
            kw = {"min": array.min(0).tolist(), "max": array.max(0).tolist()}
        accessors.append(g.Accessor(bufferView=view(array.tobytes(), target), componentType=component,
                                    count=len(array), type=kind, **kw))
        return len(accessors) - 1

    prims = primitives()
    A = armature_world(moved)
    Mw = mesh_world(moved)
    arm_trs, mesh_trs = _trs(moved, True), _trs(moved, False)
    # Joints: frames along the mesh's +Y, placed in the mesh's space, then into the armature's.
    nodes = [g.Node(name="Armature", translation=list(arm_trs[0]), rotation=list(arm_trs[1]),
                    scale=list(arm_trs[2]), children=[])]
    mesh_local = trs_matrix(mesh_trs)
    local_of, node_of, world_of = {}, {}, {}
    for name, parent, y in JOINTS:
        in_armature = mesh_local @ np.array([[1, 0, 0, 0], [0, 1, 0, y], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        u, _, vt = np.linalg.svd(in_armature[:3, :3])  # joint frames are rigid in the armature
        in_armature[:3, :3] = u @ vt
        parent_in = np.eye(4) if parent is None else local_of[parent]
        local = np.linalg.inv(parent_in) @ in_armature
        local_of[name] = in_armature
        world_of[name] = A @ in_armature
        nodes.append(g.Node(name=name, translation=local[:3, 3].tolist(),
                            rotation=Rotation.from_matrix(local[:3, :3]).as_quat().tolist(), children=[]))
        node_of[name] = len(nodes) - 1
        (nodes[0] if parent is None else nodes[node_of[parent]]).children.append(node_of[name])
    nodes.append(g.Node(name="Marker", translation=[0.0, 0.2, 0.0], children=None))
    nodes[node_of["mid"]].children.append(len(nodes) - 1)
    written = []
    for material, prim in enumerate(prims):
        W = prim["W"]
        order = np.argsort(-W, axis=1)
        joints = np.zeros((len(W), 4), np.uint8)
        weights = np.zeros((len(W), 4), np.float32)
        joints[:, :3] = order
        weights[:, :3] = np.take_along_axis(W, order, axis=1)
        attributes = g.Attributes(
            POSITION=accessor(prim["V"], g.FLOAT, g.VEC3, minmax=True),
            NORMAL=accessor(prim["N"], g.FLOAT, g.VEC3),
            TEXCOORD_0=accessor(prim["uv0"], g.FLOAT, g.VEC2),
            JOINTS_0=accessor(joints, g.UNSIGNED_BYTE, g.VEC4),
            WEIGHTS_0=accessor(weights, g.FLOAT, g.VEC4))
        if prim["uv1"] is not None:
            attributes.TEXCOORD_1 = accessor(prim["uv1"], g.FLOAT, g.VEC2)
        if prim["colours"] is not None:
            attributes.COLOR_0 = accessor(prim["colours"], g.FLOAT, g.VEC4)
        written.append(g.Primitive(attributes=attributes, material=material, indices=accessor(
            prim["F"].reshape(-1).astype(np.uint16), g.UNSIGNED_SHORT, g.SCALAR)))
    ibm = np.array([(np.linalg.inv(world_of[n]) @ Mw).T.reshape(-1) for n in NAMES], np.float32)
    png = png_bytes()
    if binary:
        image = g.Image(name="pillar_skin", mimeType="image/png", bufferView=view(png))
    else:
        image = g.Image(name="pillar_skin", uri=IMAGE)
        if image_file:
            (path.parent / IMAGE).write_bytes(png)
    nodes.append(g.Node(name="pillar", mesh=0, skin=0, translation=list(mesh_trs[0]),
                        rotation=list(mesh_trs[1]), scale=list(mesh_trs[2])))
    nodes[0].children.append(len(nodes) - 1)
    doc = g.GLTF2(
        asset=g.Asset(version="2.0", generator="puppet tests"), scene=0,
        scenes=[g.Scene(name="Scene", nodes=[0])], nodes=nodes,
        skins=[g.Skin(name="Armature", joints=[node_of[n] for n in NAMES],
                      inverseBindMatrices=accessor(ibm, g.FLOAT, g.MAT4))],
        meshes=[g.Mesh(name="pillar", primitives=written)],
        materials=[g.Material(name="skin", doubleSided=False, pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorTexture=g.TextureInfo(index=0), baseColorFactor=[1.0, 0.9, 0.8, 1.0],
            metallicFactor=0.0, roughnessFactor=0.7)),
                   g.Material(name="cap", pbrMetallicRoughness=g.PbrMetallicRoughness(
                       baseColorFactor=[0.2, 0.3, 0.9, 1.0], metallicFactor=0.5, roughnessFactor=0.4))],
        textures=[g.Texture(sampler=0, source=0)],
        samplers=[g.Sampler(magFilter=9728, minFilter=9728, wrapS=10497, wrapT=10497)],
        images=[image], accessors=accessors, bufferViews=views,
        buffers=[g.Buffer(byteLength=len(blob))])
    if binary:
        doc.set_binary_blob(bytes(blob))
        doc.save_binary(str(path))
    else:
        import base64

        doc.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode()
        doc.save_json(str(path))
    return path


def rest_vertices(moved=True) -> np.ndarray:
    """(n, 3) model-frame (glTF world) rest positions of every file vertex, in file order."""
    V = file_vertices().astype(np.float64)
    Mw = mesh_world(moved)
    return V @ Mw[:3, :3].T + Mw[:3, 3]
