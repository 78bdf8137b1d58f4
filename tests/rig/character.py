"""Skinned glTF test characters built from code, as Blender exports them: the one builder of the tests.

A ``Character`` is a description (joints, primitives, node transforms, materials, a texture);
``document`` / ``write`` turn any of them into a glTF file. Two shapes:

- the creature (``creature(...)``): a capped tube body along +Z (glTF forward), +Y up, with leg
  tubes below it (one primitive each), under an "Armature" node that is not a joint. Joints,
  nested, Blender-style (each bone's local +Y runs along the bone), with puppet's names or
  (``blender_names``) Blender's dotted ones:

      hips (root) ─ spine ─ neck ─ head
                 ├ tail base ─ tail tip          (Blender: tail ─ tail.001)
                 ├ leg.L ─ foot.L                (Blender: thigh.L ─ shin.L)
                 └ leg.R ─ foot.R                (with legs=("L", "R"))

  Options: ``split`` (UV seams, below; False writes the same surface with no copies, so that
  welding the split file must give exactly the unsplit one), ``moved`` (Armature and mesh nodes
  moved, turned, unevenly scaled), ``dressed`` (NORMAL, two UV sets, COLOR_0, a textured and a
  plain material), ``extra_joint``. Two presets: the beast (``beast``; ``build``, ``write_glb``,
  ``mesh``, ``rest_vertices``: rig, loop, fuzz, export and README tests) and the mare (``mare``,
  ``mare_rig_text``: tests/export/blender).
- the pillar (``pillar(moved)``; tests/export/test_export_source_scene.py): a tube along the mesh's
  +Y, three joints (root, mid, top); its sides (material "skin", textured, TEXCOORD_1 and
  COLOR_0) and its caps (material "cap", colour factors only, no TEXCOORD_1 or COLOR_0) are two
  primitives; a "Marker" empty is a child of "mid". Written as .glb (image embedded) or .gltf
  (image ``PILLAR_IMAGE`` next to it).

Seams: each tube ring repeats its first vertex at its end (u = 0 and u = 1) and each cap has its
own copies of its ring (a hard edge). Skinning follows Blender's exporter: positions are in the
mesh node's space and each inverse bind matrix is ``inverse(joint world) @ mesh world``, so the
rest pose puts every vertex at ``mesh world @ position`` (``rest_vertices()``, model space = the
glTF scene's world).
"""

# No ``from __future__ import annotations``: the dataclasses here must work in a module loaded by path.
import base64
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pygltflib as g
from scipy.spatial.transform import Rotation

IDENTITY_TRS = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (1.0, 1.0, 1.0))


# -- shared parts ------------------------------------------------------------------------------

def trs_matrix(trs) -> np.ndarray:
    """(4, 4) T @ R @ S of a (translation, quaternion xyzw, scale) triple."""
    t, q, s = trs
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix() * np.asarray(s, float)[None, :]
    m[:3, 3] = t
    return m


def bone_frame(direction) -> np.ndarray:
    """(3, 3) rest frame, columns = local x, y, z: y along the bone, x the character's left (+X)
    where possible (Blender's roll 0 for these bones)."""
    y = np.asarray(direction, float)
    x = np.array([1.0, 0.0, 0.0])
    x = x - (x @ y) * y
    x /= np.linalg.norm(x)
    return np.column_stack([x, y, np.cross(x, y)])


def frame_at(rotation: np.ndarray, head) -> np.ndarray:
    """(4, 4) of a (3, 3) frame placed at ``head``."""
    m = np.eye(4)
    m[:3, :3] = rotation
    m[:3, 3] = head
    return m


@dataclass
class Tube:
    """A capped tube: V (n, 3), F (f, 3) wound outwards, UV (n, 2) or None (unsplit), N (n, 3)
    normals (smooth sides, seam copies equal; flat caps), side_vertices / side_faces: the sides
    come first (rings x columns vertices), then each cap (its ring copies, its centre)."""

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray | None
    N: np.ndarray
    side_vertices: int
    side_faces: int


def tube(start, end, rings: int, radius: float, sides: int, split: bool = True) -> Tube:
    """A capped tube from ``start`` to ``end`` (3-vectors), each ring starting at the side
    nearest +X. split: each ring repeats its first vertex at its end with u = 1 (a UV seam) and
    each cap has its own ring copies (a hard edge); False: no copies and no UVs."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = (end - start) / np.linalg.norm(end - start)
    side = np.array([1.0, 0.0, 0.0]) - axis[0] * axis
    side /= np.linalg.norm(side)
    other = np.cross(axis, side)
    cols = sides + 1 if split else sides
    V, UV = [], []
    for t in np.linspace(0.0, 1.0, rings):
        for j in range(cols):
            a = 2 * np.pi * j / sides
            V.append(start + (end - start) * t + radius * (np.cos(a) * side + np.sin(a) * other))
            UV.append((j / sides, t))
    F = []
    for i in range(rings - 1):
        for j in range(sides):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            F += [[a, a + cols, b], [b, a + cols, b + cols]]
    side_vertices, side_faces = len(V), len(F)
    for ring_index, centre_point in ((0, start), (rings - 1, end)):
        ring = [ring_index * cols + j for j in range(sides)]
        if split:
            ring = []
            for j in range(sides):
                a = 2 * np.pi * j / sides
                V.append(V[ring_index * cols + j])
                UV.append((0.5 + 0.25 * np.cos(a), 0.5 + 0.25 * np.sin(a)))
                ring.append(len(V) - 1)
        V.append(centre_point)
        UV.append((0.5, 0.5))
        centre = len(V) - 1
        for j in range(sides):
            tri = [centre, ring[j], ring[(j + 1) % sides]]
            F.append(tri if ring_index == 0 else tri[::-1])
    V, F = np.array(V), np.array(F, np.int64)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    if np.einsum("ij,ij->i", a - V.mean(0), np.cross(b - a, c - a)).sum() < 0:  # outward
        F = F[:, ::-1]
    N = np.zeros_like(V)
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    for k in range(3):
        np.add.at(N, F[:, k], cross)
    if split:  # the seam's copies share one normal: the surface is smooth across it
        first, last = np.arange(0, side_vertices, cols), np.arange(sides, side_vertices, cols)
        N[first] = N[last] = N[first] + N[last]
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    return Tube(V, F, np.array(UV) if split else None, N, side_vertices, side_faces)


def hat_weights(coordinate, centres, columns, count) -> np.ndarray:
    """(n, count) weights: hat functions of one coordinate around each bone centre (columns:
    the bones' indices), at most two influences per vertex."""
    centres = np.asarray(centres, float)
    W = np.zeros((len(coordinate), count))
    spacing = np.abs(np.diff(centres)).min()
    for c, col in zip(centres, columns):
        W[:, col] = np.clip(1.0 - np.abs(coordinate - c) / spacing, 0.0, None)
    top = np.argsort(-W, axis=1)[:, :2]
    keep = np.zeros_like(W, bool)
    np.put_along_axis(keep, top, True, axis=1)
    W = np.where(keep, W, 0.0)
    empty = W.sum(1) == 0
    W[empty, np.asarray(columns)[np.argmin(np.abs(coordinate[empty, None] - centres), axis=1)]] = 1.0
    return W / W.sum(axis=1, keepdims=True)


def second_uvs(uv0: np.ndarray) -> np.ndarray:
    """A second UV set (TEXCOORD_1): the first one transposed."""
    return np.ascontiguousarray(uv0[:, ::-1])


def colours(uv0: np.ndarray) -> np.ndarray:
    """(n, 4) RGBA vertex colours (COLOR_0) that vary over the surface: (u, v, 0.5, 1)."""
    return np.column_stack([uv0, np.full(len(uv0), 0.5), np.ones(len(uv0))])


def png_bytes() -> bytes:
    """A 4x4 RGBA PNG checker (the characters' texture)."""
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


# -- the builder -------------------------------------------------------------------------------

@dataclass
class Character:
    """A skinned glTF character.

    joints: [(name, parent name or None, (4, 4) rest frame in the Armature node's space)].
    primitives: dicts of V (n, 3) mesh-node space, F (f, 3) local indices, W (n, joints), and
      optional N (n, 3), uv0 / uv1 (n, 2), colours (n, 4), material (index).
    armature_trs, mesh_trs: (translation, quaternion xyzw, scale) of the Armature node and of the
      mesh node; mesh_under_armature: the mesh node is the Armature's child (else a scene root).
    materials: glTF materials; image: (name, file name) of the texture's PNG (``png_bytes``) that
      texture 0 shows, or None; sampler: texture 0's sampler.
    empties: [(name, parent joint, translation)] nodes that are not joints.
    """

    name: str
    joints: list
    primitives: list
    armature_trs: tuple = IDENTITY_TRS
    mesh_trs: tuple = IDENTITY_TRS
    mesh_under_armature: bool = True
    materials: list = field(default_factory=list)
    image: tuple | None = None
    sampler: g.Sampler = field(default_factory=g.Sampler)
    empties: list = field(default_factory=list)
    scene_name: str | None = None

    @property
    def names(self) -> tuple:
        return tuple(j[0] for j in self.joints)

    def armature_world(self) -> np.ndarray:
        """(4, 4) world transform of the Armature node."""
        return trs_matrix(self.armature_trs)

    def mesh_world(self) -> np.ndarray:
        """(4, 4) world transform of the mesh node."""
        parent = self.armature_world() if self.mesh_under_armature else np.eye(4)
        return parent @ trs_matrix(self.mesh_trs)

    def file_vertices(self) -> np.ndarray:
        """(n, 3) mesh-space positions of every file vertex, primitives in order."""
        return np.concatenate([p["V"] for p in self.primitives])

    def rest_vertices(self) -> np.ndarray:
        """(n, 3) model-space (glTF world) rest positions of every file vertex, in file order."""
        M = self.mesh_world()
        return self.file_vertices().astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def document(character: Character, *, binary: bool = True, skins: int = 1,
             ibm_override: dict | None = None) -> tuple[g.GLTF2, bytes]:
    """(GLTF2 document, binary blob) of ``character``. binary False: the image is named by its
    file name (uri) instead of embedded. skins: 2 adds a second skinned mesh ("twin", the first
    primitive) with its own skin. ibm_override: {joint name: (4, 4)} written instead of that
    joint's inverse bind matrix."""
    blob = bytearray()
    views, accessors = [], []

    def view(data: bytes, target=None) -> int:
        while len(blob) % 4:
            blob.append(0)
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        return len(views) - 1

    def accessor(array, component, kind, minmax=False) -> int:
        array = np.ascontiguousarray(array)
        kw = {"min": array.min(0).tolist(), "max": array.max(0).tolist()} if minmax else {}
        accessors.append(g.Accessor(bufferView=view(array.tobytes()), componentType=component,
                                    count=len(array), type=kind, **kw))
        return len(accessors) - 1

    c = character
    A, M = c.armature_world(), c.mesh_world()
    t, q, s = c.armature_trs
    kw = {} if np.allclose(q, [0, 0, 0, 1]) and np.allclose(s, 1) else {"rotation": list(q), "scale": list(s)}
    nodes = [g.Node(name="Armature", translation=list(t), children=[], **kw)]
    node_of, world = {}, {}
    for name, parent, rest in c.joints:
        world[name] = A @ rest
        local = np.linalg.inv(A if parent is None else world[parent]) @ world[name]
        nodes.append(g.Node(name=name, translation=local[:3, 3].tolist(),
                            rotation=Rotation.from_matrix(local[:3, :3]).as_quat().tolist(), children=[]))
        node_of[name] = len(nodes) - 1
        (nodes[0] if parent is None else nodes[node_of[parent]]).children.append(node_of[name])
    for name, parent, translation in c.empties:
        nodes.append(g.Node(name=name, translation=list(translation)))
        nodes[node_of[parent]].children.append(len(nodes) - 1)

    written = []
    for prim in c.primitives:
        W = np.zeros((len(prim["W"]), max(4, prim["W"].shape[1])))
        W[:, :prim["W"].shape[1]] = prim["W"]
        order = np.argsort(-W, axis=1, kind="stable")[:, :4]
        weights = np.take_along_axis(W, order, axis=1)
        attributes = g.Attributes(
            POSITION=accessor(prim["V"].astype(np.float32), g.FLOAT, g.VEC3, minmax=True),
            JOINTS_0=accessor(np.where(weights > 0, order, 0).astype(np.uint16), g.UNSIGNED_SHORT, g.VEC4),
            WEIGHTS_0=accessor(weights.astype(np.float32), g.FLOAT, g.VEC4))
        for attribute, key, kind in (("NORMAL", "N", g.VEC3), ("TEXCOORD_0", "uv0", g.VEC2),
                                     ("TEXCOORD_1", "uv1", g.VEC2), ("COLOR_0", "colours", g.VEC4)):
            if prim.get(key) is not None:
                setattr(attributes, attribute, accessor(prim[key].astype(np.float32), g.FLOAT, kind))
        written.append(g.Primitive(attributes=attributes, material=prim.get("material"), indices=accessor(
            prim["F"].reshape(-1).astype(np.uint32), g.UNSIGNED_INT, g.SCALAR)))

    ibm = []
    for name in c.names:
        m = np.linalg.inv(world[name]) @ M
        if ibm_override and name in ibm_override:
            m = np.asarray(ibm_override[name], float)
        ibm.append(m.T.reshape(-1))  # column-major
    skin_list = [g.Skin(name="Armature", joints=[node_of[n] for n in c.names],
                        inverseBindMatrices=accessor(np.array(ibm, np.float32), g.FLOAT, g.MAT4))]
    t, q, s = c.mesh_trs
    kw = {} if not c.mesh_under_armature else {"translation": list(t), "rotation": list(q), "scale": list(s)}
    nodes.append(g.Node(name=c.name, mesh=0, skin=0, **kw))
    meshes = [g.Mesh(name=c.name, primitives=written)]
    scene_nodes = [0]
    if c.mesh_under_armature:
        nodes[0].children.append(len(nodes) - 1)
    else:
        scene_nodes.append(len(nodes) - 1)
    if skins == 2:
        skin_list.append(g.Skin(name="Second", joints=skin_list[0].joints,
                                inverseBindMatrices=skin_list[0].inverseBindMatrices))
        meshes.append(g.Mesh(name="twin", primitives=written[:1]))
        nodes.append(g.Node(name="twin", mesh=1, skin=1))
        scene_nodes.append(len(nodes) - 1)

    images, textures, samplers = [], [], []
    if c.image is not None:
        image_name, file_name = c.image
        images = [g.Image(name=image_name, mimeType="image/png", bufferView=view(png_bytes())) if binary
                  else g.Image(name=image_name, uri=file_name)]
        textures, samplers = [g.Texture(sampler=0, source=0)], [c.sampler]
    doc = g.GLTF2(asset=g.Asset(version="2.0", generator="puppet tests"), scene=0,
                  scenes=[g.Scene(name=c.scene_name, nodes=scene_nodes)], nodes=nodes, skins=skin_list,
                  meshes=meshes, materials=list(c.materials), textures=textures, samplers=samplers,
                  images=images, accessors=accessors, bufferViews=views,
                  buffers=[g.Buffer(byteLength=len(blob))])
    return doc, bytes(blob)


def write(path, character: Character, *, image_file: bool = True, **kwargs) -> Path:
    """Write ``character`` to ``path``: .glb (the image embedded) or .gltf (the buffer as a data
    uri, the image as its file next to it, written unless ``image_file`` is False). kwargs: as
    ``document``. Returns the path."""
    path = Path(path)
    binary = path.suffix.lower() == ".glb"
    doc, blob = document(character, binary=binary, **kwargs)
    if binary:
        doc.set_binary_blob(blob)
        doc.save_binary(str(path))
    else:
        doc.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
        doc.save_json(str(path))
        if character.image is not None and image_file:
            (path.parent / character.image[1]).write_bytes(png_bytes())
    return path


# -- the creature: beast and mare ---------------------------------------------------------------

SIDES = 10
ARMATURE_OFFSET = np.array([0.0, 0.6, 0.0])

# name (puppet's, Blender's), parent, head (armature space), direction of the bone's local +Y;
# legs: one chain per side (the R side mirrors x).
_BODY = (
    ("hips", "hips", None, (0.0, 0.0, 0.0), (0, 0, 1)),
    ("spine", "spine", "hips", (0.0, 0.0, 0.5), (0, 0, 1)),
    ("neck", "neck", "spine", (0.0, 0.0, 1.0), (0, 0, 1)),
    ("head", "head", "neck", (0.0, 0.0, 1.4), (0, 0, 1)),
    ("tail base", "tail", "hips", (0.0, 0.0, -0.1), (0, 0, -1)),
    ("tail tip", "tail.001", "tail base", (0.0, 0.0, -0.5), (0, 0, -1)),
)
_LEG = (("leg.{}", "thigh.{}", "hips", (0.18, 0.0, 0.25), (0, -1, 0)),
        ("foot.{}", "shin.{}", "leg.{}", (0.18, -0.35, 0.25), (0, -1, 0)))


def creature_bones(legs=("L",), blender_names: bool = False) -> list:
    """[(name, parent, head, direction)] of the body and one leg per side in ``legs``; names
    puppet's ("tail base", "leg.L", ...) or Blender's ("tail.001", "thigh.L", ...)."""
    rename = {}
    rows = list(_BODY)
    for side in legs:
        x = 1.0 if side == "L" else -1.0
        rows += [(ours.format(side), theirs.format(side), parent.format(side),
                  (x * head[0], head[1], head[2]), direction) for ours, theirs, parent, head, direction in _LEG]
    for ours, theirs, *_ in rows:
        rename[ours] = theirs if blender_names else ours
    return [(rename[ours], rename.get(parent), head, direction) for ours, _, parent, head, direction in rows]


BONES = tuple(creature_bones())
NAMES = tuple(b[0] for b in BONES)


def _creature_parts(split, legs, names):
    """[(Tube, W (n, len(names)))] body then each leg, armature space, rest pose."""
    body = tube((0.0, 0.0, -0.7), (0.0, 0.0, 1.8), 26, 0.25, SIDES, split)
    parts = [(body, hat_weights(body.V[:, 2], [-0.6, -0.3, 0.15, 0.7, 1.2, 1.6],
                                [5, 4, 0, 1, 2, 3], len(names)))]  # tail tip, tail base, hips, spine, neck, head
    for k, side in enumerate(legs):
        x = 0.18 if side == "L" else -0.18
        leg = tube((x, -0.05, 0.25), (x, -0.7, 0.25), 8, 0.07, SIDES, split)
        parts.append((leg, hat_weights(leg.V[:, 1], [-0.15, -0.55], [6 + 2 * k, 7 + 2 * k], len(names))))
    return parts


def mesh(split: bool = True):
    """The beast's primitives [(V (n, 3) float32, F (f, 3), W (n, bones))], model space less
    ARMATURE_OFFSET (rest pose)."""
    return [(part.V.astype(np.float32), part.F, W) for part, W in _creature_parts(split, ("L",), NAMES)]


MOVED_ARMATURE_TRS = ((1.5, 0.3, 2.0), tuple(Rotation.from_euler("y", 25, degrees=True).as_quat()),
                      (1.2, 1.0, 0.8))
MOVED_MESH_TRS = ((0.1, -0.05, 0.2), tuple(Rotation.from_euler("x", 10, degrees=True).as_quat()),
                  (1.0, 1.1, 0.9))


def creature(split: bool = True, *, name: str = "beast", legs=("L",), blender_names: bool = False, moved: bool = False,
             dressed: bool = False, extra_joint: str | None = None) -> Character:
    """The creature, its mesh named ``name``. split: UV seams (see the module docstring); legs: "L" and/or "R";
    blender_names: Blender's bone names; moved: the Armature node and the mesh node (its child)
    moved, turned and unevenly scaled (MOVED_ARMATURE_TRS, MOVED_MESH_TRS; else the Armature only
    moved by ARMATURE_OFFSET, the mesh node a scene root); dressed: NORMAL, two UV sets, COLOR_0,
    materials "coat" (body, textured) and "hoof" (legs, plain); extra_joint: the name of one
    more joint (child of head) that no vertex follows."""
    bones = creature_bones(legs, blender_names)
    names = [b[0] for b in bones]
    bones += [(extra_joint, "head", (0.0, 0.0, 1.7), (0, 0, 1))] if extra_joint else []
    joints = [(name, parent, frame_at(bone_frame(direction), head)) for name, parent, head, direction in bones]
    if moved:
        armature_trs, mesh_trs = MOVED_ARMATURE_TRS, MOVED_MESH_TRS
    else:
        armature_trs, mesh_trs = (tuple(ARMATURE_OFFSET), (0.0, 0.0, 0.0, 1.0), (1.0, 1.0, 1.0)), IDENTITY_TRS
    character = Character(name, joints, [], armature_trs, mesh_trs,
                          mesh_under_armature=moved)
    to_mesh = np.linalg.inv(character.mesh_world()) @ character.armature_world()  # armature -> mesh space
    for k, (part, W) in enumerate(_creature_parts(split, legs, names)):
        prim = {"V": (part.V @ to_mesh[:3, :3].T + to_mesh[:3, 3]).astype(np.float32), "F": part.F, "W": W}
        if dressed:
            N = part.N @ np.linalg.inv(to_mesh[:3, :3])
            prim.update(N=N / np.linalg.norm(N, axis=1, keepdims=True), uv0=part.UV, uv1=second_uvs(part.UV),
                        colours=colours(part.UV), material=0 if k == 0 else 1)
        character.primitives.append(prim)
    if dressed:
        character.materials = [
            g.Material(name="coat", pbrMetallicRoughness=g.PbrMetallicRoughness(
                baseColorTexture=g.TextureInfo(index=0, texCoord=0), metallicFactor=0.0)),
            g.Material(name="hoof", pbrMetallicRoughness=g.PbrMetallicRoughness(
                baseColorFactor=[0.2, 0.15, 0.1, 1.0], metallicFactor=0.0))]
        character.image = ("coat", "coat.png")
    return character


def beast(split: bool = True, extra_joint: str | None = None) -> Character:
    """The beast: the creature with one leg, puppet's names, not moved, undressed."""
    return creature(split, extra_joint=extra_joint)


def mare() -> Character:
    """The mare: the creature with two legs, Blender's names, moved and dressed."""
    return creature(name="mare", legs=("L", "R"), blender_names=True, moved=True, dressed=True)


def build(split: bool = True, *, skins: int = 1, ibm_override: dict | None = None,
          extra_joint: str | None = None):
    """(GLTF2 document, binary blob) of the beast (``document``'s skins and ibm_override)."""
    return document(beast(split, extra_joint), skins=skins, ibm_override=ibm_override)


def write_glb(path, split: bool = True, **kwargs):
    """Write the beast as a .glb at ``path``; returns the path."""
    doc, blob = build(split, **kwargs)
    doc.set_binary_blob(blob)
    doc.save_binary(str(path))
    return Path(path)


def rest_vertices(split: bool = True) -> np.ndarray:
    """(n, 3) model-space rest positions of every beast file vertex, primitives in order."""
    return beast(split).rest_vertices()


# The servos of the mare's rig: joint -> (id, axis); the solve fills in the other joints.
MARE_SERVOS = {"spine": (1, "x"), "neck": (2, "z"), "tail": (3, "x"), "thigh.L": (4, "x"), "thigh.R": (5, "z")}


def mare_rig_text(glb_name: str) -> str:
    """A rig file for the mare (the mesh next to it): MARE_SERVOS, hips held still."""
    lines = ['name = "mare"', f'mesh = "{glb_name}"', 'fixed = ["hips"]', "",
             "[solver]", "clusters = 30", "extra_weights = 0", 'energy = "spokes_and_rims"']
    for joint, (servo_id, axis) in MARE_SERVOS.items():
        lines += ["", "[[servo]]", f"id = {servo_id}", 'model = "XL330-M288"', f'joint = "{joint}"',
                  f'axis = "{axis}"', "zero_ticks = 2048", "limits_deg = [-60, 60]"]
    return "\n".join(lines) + "\n"


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


# -- pillar ------------------------------------------------------------------------------------

PILLAR_SIDES = 8
PILLAR_RINGS = 7
PILLAR_HEIGHT = 2.0
PILLAR_JOINTS = (("root", None, 0.0), ("mid", "root", 0.7), ("top", "mid", 1.4))  # name, parent, y
PILLAR_IMAGE = "pillar_skin.png"
# (translation, rotation quaternion x y z w, scale) of the Armature node and of the mesh node
# (relative to the Armature node): moved, turned and squashed.
PILLAR_ARMATURE_TRS = ((1.5, 0.3, 2.0), tuple(Rotation.from_euler("xyz", [20, -35, 10], degrees=True).as_quat()),
                       (1.2, 1.0, 0.8))
PILLAR_MESH_TRS = ((0.1, -0.2, 0.05), tuple(Rotation.from_euler("xyz", [0, 15, 0], degrees=True).as_quat()),
                   (1.1, 0.9, 1.0))


def pillar(moved=True) -> Character:
    """The pillar. moved: True (PILLAR_ARMATURE_TRS, PILLAR_MESH_TRS), False (no transforms) or
    the Armature's own (translation, quaternion, scale) with PILLAR_MESH_TRS. Its primitives are
    "sides" (material 0, the textured skin, TEXCOORD_1 and COLOR_0) and "caps" (material 1, plain)."""
    if moved is True:
        armature_trs, mesh_trs = PILLAR_ARMATURE_TRS, PILLAR_MESH_TRS
    elif moved is False:
        armature_trs, mesh_trs = IDENTITY_TRS, IDENTITY_TRS
    else:
        armature_trs, mesh_trs = moved, PILLAR_MESH_TRS
    shape = tube((0, 0, 0), (0, PILLAR_HEIGHT, 0), PILLAR_RINGS, 0.3, PILLAR_SIDES)
    W = hat_weights(shape.V[:, 1], [y + 0.35 for _, _, y in PILLAR_JOINTS], [0, 1, 2], 3)
    n, f = shape.side_vertices, shape.side_faces
    uv0 = shape.UV.astype(np.float32)
    sides = {"V": shape.V[:n].astype(np.float32), "F": shape.F[:f], "W": W[:n], "N": shape.N[:n],
             "uv0": uv0[:n], "uv1": second_uvs(uv0[:n]), "colours": colours(uv0[:n]).astype(np.float32),
             "material": 0}
    caps = {"V": shape.V[n:].astype(np.float32), "F": shape.F[f:] - n, "W": W[n:], "N": shape.N[n:],
            "uv0": uv0[n:], "uv1": None, "colours": None, "material": 1}
    # Joints: frames along the mesh's +Y placed in the Armature's space, made rigid there.
    mesh_local = trs_matrix(mesh_trs)
    rotation = np.linalg.svd(mesh_local[:3, :3])
    joints = [(name, parent, frame_at(rotation[0] @ rotation[2], mesh_local[:3, :3] @ (0, y, 0) + mesh_local[:3, 3]))
              for name, parent, y in PILLAR_JOINTS]
    materials = [
        g.Material(name="skin", doubleSided=False, pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorTexture=g.TextureInfo(index=0), baseColorFactor=[1.0, 0.9, 0.8, 1.0],
            metallicFactor=0.0, roughnessFactor=0.7)),
        g.Material(name="cap", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=[0.2, 0.3, 0.9, 1.0], metallicFactor=0.5, roughnessFactor=0.4))]
    return Character("pillar", joints, [sides, caps], armature_trs, mesh_trs, materials=materials,
                     image=("pillar_skin", PILLAR_IMAGE), empties=[("Marker", "mid", (0.0, 0.2, 0.0))],
                     sampler=g.Sampler(magFilter=9728, minFilter=9728, wrapS=10497, wrapT=10497),
                     scene_name="Scene")


def chain(joints: int, *, bone_length: float = 0.05, sides: int = 6) -> Character:
    """A snake of ``joints`` joints in one chain along +Z (each a child of the one before), a
    capped tube around them, each vertex following the two nearest joints: a model as large as a
    test of many joints needs (e.g. 1000), built in a second."""
    heads = [(0.0, 0.0, k * bone_length) for k in range(joints)]
    bones = [(f"j{k}", f"j{k - 1}" if k else None, frame_at(bone_frame((0, 0, 1)), head))
             for k, head in enumerate(heads)]
    body = tube((0.0, 0.0, 0.0), (0.0, 0.0, joints * bone_length), joints + 1, 0.1, sides, split=False)
    centres = (np.arange(joints) + 0.5) * bone_length
    W = hat_weights(body.V[:, 2], centres, list(range(joints)), joints)
    return Character("snake", bones, [{"V": body.V.astype(np.float32), "F": body.F, "W": W}])


def write_chain_glb(path, joints: int, **kwargs) -> Path:
    """Write ``chain(joints)`` as a .glb at ``path``; returns the path."""
    doc, blob = document(chain(joints, **kwargs))
    doc.set_binary_blob(blob)
    doc.save_binary(str(path))
    return Path(path)
