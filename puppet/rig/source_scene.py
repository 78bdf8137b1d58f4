"""What a glTF character file holds besides the skinned geometry: its look and its place.

Read once when a rig loads from a .glb/.gltf (``puppet.rig.gltf.read_gltf``) and kept with the rig
(``Rig.source``) so that exports carry it: per file vertex attributes (normals, tangents, every
TEXCOORD_n and COLOR_n set), the primitives with their own triangles and materials, the
materials with their textures, samplers and images, and the node hierarchy with each node's
transform. Characters that are not glTF (the built-in critter, OBJ/PLY) have none. Nothing here
is used by the solve or per frame.

Spaces: the model frame is the file's world (the scene root). ``object_world`` is the world
transform of the node that Blender's glTF importer makes the armature object: the deepest common
ancestor of the skin's joints (and its ``skeleton``), or that node's parent when it is a joint
itself, or the scene root (identity) when the joints have no common ancestor. The importer makes
the skinned mesh a child of that object with an identity transform, whatever the mesh node's own
transform (glTF ignores it for a skinned mesh): its vertex coordinates are in this space.

Images: embedded ones (a .glb's bufferView, a data uri) are kept as bytes; a file next to a
.gltf is kept as its path, checked at load. A missing or unreadable image gives a warning naming
the file (``warnings``) and the textures that use it are left out (``Texture.source`` None):
exports write those materials plain (their factors, no texture).
"""

from __future__ import annotations

import base64
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from puppet.rig.errors import RigError

#: Vertex attributes carried per file vertex (besides POSITION and the skin's JOINTS/WEIGHTS).
CARRIED = ("NORMAL", "TANGENT", "TEXCOORD_", "COLOR_")
#: Components per vertex the glTF spec allows for each of them.
WIDTHS = {"NORMAL": (3,), "TANGENT": (4,), "TEXCOORD": (2,), "COLOR": (3, 4)}
#: Image types a glTF 2.0 file may hold without an extension.
IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}


@dataclass
class SourceNode:
    """One node of the file, in the file's node order.

    name: node name or None; parent: node index or -1; children: node indices.
    translation, rotation (x, y, z, w), scale: as written (None: absent); matrix: 16 floats
    column-major as written, or None. local, world: (4, 4) float64 transforms (world at rest).
    joint: the rig bone it is (index into the skeleton) or -1. mesh: the position of this node in
    ``SourceScene.mesh_nodes`` (a skinned mesh node the rig read) or -1.
    """

    name: str | None
    parent: int
    children: list[int]
    translation: list[float] | None
    rotation: list[float] | None
    scale: list[float] | None
    matrix: list[float] | None
    local: np.ndarray
    world: np.ndarray
    joint: int = -1
    mesh: int = -1


@dataclass
class SourcePrimitive:
    """One triangle primitive: file vertices start..start+count-1 (file order, all primitives
    concatenated); indices (3t,) int64 into those count vertices; material index or None;
    attributes: the carried attribute names it has."""

    start: int
    count: int
    indices: np.ndarray
    material: int | None
    attributes: tuple[str, ...]


@dataclass
class SourceImage:
    """An image: name, mime type, and its bytes (embedded) or the file it names (``path``)."""

    name: str | None
    mime_type: str
    data: bytes | None = None
    path: Path | None = None

    def read(self) -> tuple[bytes | None, str | None]:
        """(the image's bytes, None), or (None, a warning naming the file) when the file has gone
        since the rig loaded: an exporter then leaves its textures out (plain materials)."""
        if self.data is not None:
            return self.data, None
        try:
            return Path(self.path).read_bytes(), None
        except OSError as e:
            return None, (f"{self.path}: cannot read the image ({e.strerror}): its textures are "
                          "left out (the materials are exported plain)")


@dataclass
class SourceScene:
    """The look and place of a glTF character (see the module docstring).

    path:         the character file.
    nodes:        every node (SourceNode), the file's order.
    roots:        the nodes of the file's default scene (all parentless nodes when it has none).
    mesh_nodes:   node indices of the skinned mesh nodes read, in the rig's order; mesh_names
                  their meshes' names; primitives[k]: the primitives of mesh_nodes[k].
    attributes:   {name: (n_file, width) float32} per file vertex (where a primitive lacks it:
                  white for COLOR_n, zeros for the others).
    materials:    glTF material dicts (as in the file); textures, samplers: dicts; images:
                  SourceImage (the texture dicts' "source" index it; None: left out).
    skeleton_node: the skin's ``skeleton`` node or None.
    armature:     the node Blender makes the armature object (module docstring), None: the scene root.
    object_world: (4, 4) float64, the space of Blender's imported mesh object: armature's world.
    warnings:     what could not be carried, in words naming the file.
    """

    path: Path
    nodes: list[SourceNode]
    roots: list[int]
    mesh_nodes: list[int]
    mesh_names: list[str | None]
    primitives: list[list[SourcePrimitive]]
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    materials: list[dict] = field(default_factory=list)
    textures: list[dict] = field(default_factory=list)
    samplers: list[dict] = field(default_factory=list)
    images: list[SourceImage] = field(default_factory=list)
    skeleton_node: int | None = None
    armature: int | None = None
    object_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    warnings: list[str] = field(default_factory=list)

    @property
    def triangles(self) -> np.ndarray:
        """(t, 3) int64 every primitive's triangles as indices into the file's vertex order."""
        parts = [p.indices.reshape(-1, 3) + p.start for prims in self.primitives for p in prims]
        return np.concatenate(parts) if parts else np.zeros((0, 3), np.int64)

    def joint_worlds(self, joint_nodes) -> np.ndarray:
        """(b, 4, 4) rest world transforms of the rig's bones' nodes."""
        return np.array([self.nodes[int(j)].world for j in joint_nodes])


def _plain(obj) -> dict:
    """A pygltflib object as a JSON dict without None or empty entries."""
    def clean(value):
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items() if v is not None and v != {} and v != []}
        if isinstance(value, list):
            return [clean(v) for v in value]
        return value

    return clean(obj.to_dict())


def _image(gltf, acc, index: int, path: Path, warnings: list[str]) -> SourceImage | None:
    """Image ``index`` of the file, or None (a warning says why) when it cannot be carried."""
    image = gltf.images[index]
    name = image.name
    where = f"images[{index}]"
    if image.bufferView is not None:
        try:
            view = gltf.bufferViews[image.bufferView]
            data = acc.buffer(view.buffer)
            start = view.byteOffset or 0
            blob = data[start:start + view.byteLength]
        except (RigError, IndexError, TypeError) as err:
            warnings.append(f"{path}: {where}: unreadable embedded image ({err}); its textures are "
                            "left out (the materials are exported plain)")
            return None
        return SourceImage(name, image.mimeType or "image/png", data=bytes(blob))
    uri = image.uri or ""
    if uri.startswith("data:"):
        try:
            head, payload = uri.split(",", 1)
            data = base64.b64decode(payload)
        except ValueError as err:
            warnings.append(f"{path}: {where}: bad data uri ({err}); its textures are left out "
                            "(the materials are exported plain)")
            return None
        mime = head[5:].split(";")[0] or image.mimeType or "image/png"
        return SourceImage(name, mime, data=data)
    file = path.parent / unquote(uri)
    if not uri or not file.is_file():
        warnings.append(f"{path}: image file {str(file)!r} ({where}.uri) not found: its textures are "
                        "left out (the materials are exported plain)")
        return None
    mime = image.mimeType or IMAGE_TYPES.get(file.suffix.lower(), "image/png")
    return SourceImage(name or file.stem, mime, path=file)


def _armature_node(nodes: list[SourceNode], joints: list[int], skeleton: int | None) -> int | None:
    """Blender's armature node for a skin: the deepest common ancestor of its joints (and
    skeleton), its parent when that is a joint; None for the scene root."""
    def path_from_root(i):
        path = []
        while i is not None and i >= 0 and len(path) <= len(nodes):
            path.append(i)
            i = nodes[i].parent
        return path[::-1]

    common = None
    for i in joints + ([skeleton] if skeleton is not None else []):
        path = path_from_root(i)
        if common is None:
            common = path
        else:
            k = 0
            while k < min(len(path), len(common)) and path[k] == common[k]:
                k += 1
            common = common[:k]
    if not common:
        return None
    node = common[-1]
    if node in joints:
        node = nodes[node].parent
    return node if node is not None and node >= 0 else None


def read_source_scene(gltf, acc, path: Path, *, locals_: np.ndarray, worlds: np.ndarray,
                      parent_node: dict, mesh_nodes: list[int], joints: list[int],
                      bone_of_joint: dict[int, int], skin_index: int) -> SourceScene:
    """The SourceScene of a glTF document already read by ``read_gltf``.

    gltf: pygltflib document; acc: its accessor reader (``puppet.rig.gltf._Accessors``);
    locals_, worlds: (nodes, 4, 4) rest transforms of every node; parent_node {child: parent};
    mesh_nodes: the skinned mesh nodes read; joints: the skin's joint nodes; bone_of_joint:
    {node index: rig bone}; skin_index: the skin read.
    """
    warnings: list[str] = []
    mesh_index = {node: k for k, node in enumerate(mesh_nodes)}
    nodes = []
    for i, n in enumerate(gltf.nodes or []):
        children = [c for c in (n.children or []) if isinstance(c, int) and parent_node.get(c) == i]
        nodes.append(SourceNode(
            name=n.name if isinstance(n.name, str) else None, parent=parent_node.get(i, -1),
            children=children,
            translation=list(map(float, n.translation)) if n.translation is not None else None,
            rotation=list(map(float, n.rotation)) if n.rotation is not None else None,
            scale=list(map(float, n.scale)) if n.scale is not None else None,
            matrix=list(map(float, n.matrix)) if n.matrix is not None and len(n.matrix) == 16 else None,
            local=locals_[i], world=worlds[i], joint=bone_of_joint.get(i, -1),
            mesh=mesh_index.get(i, -1)))
    scenes = gltf.scenes or []
    default = gltf.scene if gltf.scene is not None and 0 <= gltf.scene < len(scenes) else 0
    roots = [r for r in (scenes[default].nodes or []) if isinstance(r, int) and 0 <= r < len(nodes)] \
        if scenes else []
    if not roots:
        roots = [i for i, n in enumerate(nodes) if n.parent < 0]

    # Per vertex attributes and primitives, in the order read_gltf concatenates the vertices.
    columns: dict[str, list] = {}
    primitives: list[list[SourcePrimitive]] = []
    start = 0
    for node_index in mesh_nodes:
        mesh = gltf.meshes[gltf.nodes[node_index].mesh]
        prims = []
        for p_index, prim in enumerate(mesh.primitives):
            where = f"meshes[{gltf.nodes[node_index].mesh}].primitives[{p_index}]"
            attributes = {k: v for k, v in vars(prim.attributes).items() if v is not None}
            n = acc.gltf.accessors[attributes["POSITION"]].count
            if prim.indices is not None:
                indices = acc.read(prim.indices, f"{where}.indices", normalize=False).reshape(-1)
            else:
                indices = np.arange(n)
            carried = []
            for name in sorted(attributes):
                if not name.startswith(CARRIED):
                    continue
                try:
                    values = acc.read(attributes[name], f"{where}.{name}").astype(np.float32)
                except RigError as err:  # the rig needs none of these: leave it out, say so
                    warnings.append(f"{err}; left out of exports")
                    continue
                widths = WIDTHS[name.split("_")[0] if "_" in name else name]
                if len(values) != n or values.shape[1] not in widths or not np.isfinite(values).all():
                    warnings.append(f"{path}: {where}.{name}: {len(values)} values of {values.shape[1]} "
                                    f"for {n} vertices (glTF: {' or '.join(map(str, widths))} each, "
                                    "finite); left out of exports")
                    continue
                columns.setdefault(name, []).append((start, values))
                carried.append(name)
            material = prim.material if isinstance(prim.material, int) and \
                0 <= prim.material < len(gltf.materials or []) else None
            prims.append(SourcePrimitive(start, n, indices.astype(np.int64), material, tuple(carried)))
            start += n
        primitives.append(prims)
    total = start
    attributes = {}
    for name, parts in columns.items():
        width = max(v.shape[1] for _, v in parts)
        # A primitive without a colour set is white (glTF multiplies by the colour; Blender's
        # importer fills white too); other attributes are zero there.
        array = np.full((total, width), 1.0 if name.startswith("COLOR_") else 0.0, np.float32)
        for at, values in parts:
            array[at:at + len(values), :values.shape[1]] = values
        attributes[name] = array

    images = [_image(gltf, acc, i, path, warnings) for i in range(len(gltf.images or []))]
    textures = []
    for t in gltf.textures or []:
        d = _plain(t)
        source = d.get("source")
        if not isinstance(source, int) or not 0 <= source < len(images) or images[source] is None:
            d["source"] = None
        textures.append(d)
    skin = gltf.skins[skin_index]
    skeleton = skin.skeleton if isinstance(skin.skeleton, int) and 0 <= skin.skeleton < len(nodes) else None
    armature = _armature_node(nodes, joints, skeleton)
    return SourceScene(
        path=path, nodes=nodes, roots=roots, mesh_nodes=list(mesh_nodes),
        mesh_names=[gltf.meshes[gltf.nodes[i].mesh].name for i in mesh_nodes], primitives=primitives,
        attributes=attributes, materials=[_plain(m) for m in gltf.materials or []],
        textures=textures, samplers=[_plain(s) for s in gltf.samplers or []], images=images,
        skeleton_node=skeleton, armature=armature,
        object_world=np.eye(4) if armature is None else worlds[armature].copy(),
        warnings=warnings)
