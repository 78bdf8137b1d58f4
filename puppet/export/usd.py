"""USD (.usdc/.usda/.usd, or a packaged .usdz) with usd-core: the exact deformed mesh, its look
and the animated skeleton.

Stage layout (default prim ``/<name>``):
  /<name>            Xform
  /<name>/Mesh       Mesh: faceVertexCounts/Indices, rest points as the default value, and one
                     points (and extent) time sample per frame: the FAST result itself.
  /<name>/Rig        SkelRoot
  /<name>/Rig/Skeleton  Skeleton: every joint (identifier-safe names as paths), bind and rest
                     transforms; skel:animationSource -> Anim. No mesh is bound to it (the mesh's
                     points are already deformed), so nothing is skinned twice.
  /<name>/Rig/Anim   SkelAnimation: translations, rotations (time-sampled), scales (ones).
For a rig read from a glTF file (``Rig.source``), the stage also carries the file's look and place:
  /<name>/<node>/... Xforms of the file's nodes that are not joints and not under one (their
                     names, hierarchy and transforms as written: translate/orient/scale ops, or
                     a matrix op).
  .../<armature>/<mesh>  the Mesh, named as the file's mesh node, under the Xform of the node that
                     Blender's glTF importer makes the armature object, with an identity transform:
                     its points are in that object's local space (the PC2's ``space="object"``),
                     its world is the model frame's points exactly. Its triangles are the file's;
                     primvars: ``st`` / ``st<k>`` from TEXCOORD_0 / TEXCOORD_k (t = 1 − v),
                     displayColor (+ displayOpacity) from COLOR_0, ``COLOR_<k>`` for k > 0; normals
                     per frame, smooth across UV seams, hard edges kept as the file has them; each
                     primitive's material bound (GeomSubsets when there are several).
  /<name>/Materials  UsdPreviewSurface materials (``puppet.export.usd_materials``); their images
                     are written next to the layer in ``<stem>_textures/`` and referenced from it,
                     or packaged inside a .usdz.
The Rig stays in the model frame (the skeleton's world, as the solve has it).
Stage metadata: upAxis, metersPerUnit, timeCodesPerSecond = framesPerSecond = fps,
startTimeCode 1, endTimeCode N: frame k is time code k, frame 1 the take's first reading.
The layer is saved every ``save_every`` frames, so memory stays bounded on long takes.
A .usdz is written as a .usdc layer and its textures in a temporary folder, packaged at close().
"""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

from puppet.export.errors import ExportError
from puppet.export.joint_transforms import (compose, local_transforms, matrix_to_quaternion,
                                            rest_globals)
from puppet.export.names import safe_name, safe_names
from puppet.export.usd_materials import primvar_name, write_materials, write_textures
from puppet.export.writer import ExportWriter

UP_AXES = ("Y", "Z")


def _usd():
    try:
        from pxr import Tf, Usd, UsdGeom, UsdSkel, Vt
    except ImportError as e:  # usd-core is a dependency; say so if an install lost it
        raise ExportError("--usd", f"USD export needs the usd-core package ({e})") from e
    return Tf, Usd, UsdGeom, UsdSkel, Vt


def _usd_reason(error: Exception) -> str:
    """The distinct messages of a pxr error (it lists every C++ diagnostic with its source line)."""
    found = re.findall(r" : '(.+?)'\s*$", str(error), flags=re.MULTILINE)
    unique = list(dict.fromkeys(found))
    return "; ".join(unique[:2]) if unique else str(error).strip()


def _usd_matrices(M: np.ndarray) -> np.ndarray:
    """(b, 3, 4) column-vector affines -> (b, 4, 4) USD row-vector matrices (transposed)."""
    out = np.zeros((len(M), 4, 4))
    out[:, :3, :] = M
    out[:, 3, 3] = 1.0
    return np.ascontiguousarray(np.swapaxes(out, 1, 2))


class UsdWriter(ExportWriter):
    """Writes one time sample of points and joint transforms per frame.

    path:     output file (.usdc binary, .usda text or .usd; .usdz: packaged with its textures).
    names:    b joint names; parents (b,) int; heads (b, 3) rest pivots; frames (b, 3, 3) rest frames.
    V:        (n, 3) rest vertices (output order, model frame); F (f, 3) triangles into V.
    fps:      frames per second (timeCodesPerSecond).
    up:       'Y' or 'Z': the stage's upAxis (the data is written as given).
    meters_per_unit: the stage's metersPerUnit (model units in metres).
    source:   the character file's SourceScene (``Rig.source``) or None (module docstring);
              V must then be in its vertex order.
    weld:     (n,) int: the welded vertex of each vertex (``SourceOrder.index``): copies that the
              file gave the same normal share their per-frame normal (a UV seam shades smooth),
              copies with different normals keep theirs apart (a hard edge stays hard).
    textures: the folder the images go to (default ``<stem>_textures`` next to path; a .usdz
              packages them); inputs: files no texture may overwrite.
    Fields: joint_paths (b,) the Skeleton's joint tokens; renamed {name: safe name}; mesh_path;
    warnings: what could not be written (an image that cannot be read).
    """

    close_on_error = False  # an error inside `with` releases the stage without saving more

    def __init__(self, path, *, names, parents, heads, frames, V, F, fps: float, up: str = "Y",
                 meters_per_unit: float = 1.0, name: str = "character", save_every: int = 64,
                 source=None, weld=None, textures=None, inputs=(), sync: dict | None = None):
        Tf, Usd, UsdGeom, UsdSkel, Vt = _usd()
        self._Tf, self._Vt, self._Usd = Tf, Vt, Usd
        self.path = Path(path)
        if up not in UP_AXES:
            raise ExportError(self.path, f"up axis must be one of {UP_AXES}, got {up!r}")
        self.warnings: list[str] = []
        self._package = None  # a .usdz: (temporary folder, layer inside it)
        layer = self.path
        if self.path.suffix.lower() == ".usdz":
            folder = Path(tempfile.mkdtemp(prefix=".puppet-usdz-", dir=self.path.parent))
            layer = folder / f"{safe_names([name])[0][0]}.usdc"
            self._package = (folder, layer)
            textures = folder / "textures"
        elif textures is None:
            textures = self.path.with_name(f"{self.path.stem}_textures")
        self.fps = float(fps)
        self.parents = np.asarray(parents, np.int64)
        self.rest = rest_globals(np.asarray(heads, np.float64), np.asarray(frames, np.float64))
        self.save_every = int(save_every)
        self.num_frames = 0
        self._closed = False
        safe, self.renamed = safe_names(names)
        paths: list[str] = []
        for j, p in enumerate(self.parents):
            paths.append(safe[j] if p < 0 else f"{paths[p]}/{safe[j]}")
        self.joint_paths = paths
        root = "/" + safe_names([name])[0][0]
        try:
            stage = Usd.Stage.CreateNew(str(layer))
        except Tf.ErrorException as e:
            self._drop_package()
            raise ExportError(self.path, f"cannot create USD stage: {_usd_reason(e)}") from e
        self.layer = layer
        self.stage = stage
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        stage.SetStartTimeCode(1)
        stage.SetEndTimeCode(1)
        if sync:  # the sound and start timecode (puppet.export.sync) in the layer's metadata
            stage.GetRootLayer().customLayerData = dict(sync)
        top = UsdGeom.Xform.Define(stage, root)
        stage.SetDefaultPrim(top.GetPrim())

        self._to_object = None  # (3, 4) model frame -> the mesh's local space
        self._normals = None
        mesh_path = f"{root}/Mesh"
        if source is not None:
            mesh_path, self._to_object = _source_xforms(stage, root, source)
        self.mesh_path = mesh_path
        V = np.asarray(V, np.float64)
        if self._to_object is not None:
            V = V @ self._to_object[:, :3].T + self._to_object[:, 3]
        V = V.astype(np.float32)
        F = np.asarray(F, np.int32)
        mesh = UsdGeom.Mesh.Define(stage, mesh_path)
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(F.reshape(-1))))
        self._points = mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(V))
        self._extent = mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([V.min(0), V.max(0)])))
        self._local = np.empty(V.shape, np.float32)
        if source is not None:
            groups = np.arange(len(V)) if weld is None else np.asarray(weld, np.int64)
            if "NORMAL" in source.attributes:  # copies with the file's same normal: a UV seam,
                key = np.column_stack([groups, np.round(source.attributes["NORMAL"] * 1000)])
                groups = np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)  # else a hard edge
            self._normals = _SmoothNormals(F, groups)
            self._normals_attr = mesh.CreateNormalsAttr()
            mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
            self._normals_attr.Set(Vt.Vec3fArray.FromNumpy(self._normals(V)))
            _primvars(mesh, source)
            try:
                files, self.warnings = write_textures(source, Path(textures), inputs=inputs)
            except OSError as e:
                self._drop_package()
                raise ExportError(Path(textures), f"cannot write the textures: {e.strerror or e}") from e
            materials = write_materials(stage, root, source, files, layer.parent)
            _bind(mesh, source, materials)

        skel_root = UsdSkel.Root.Define(stage, f"{root}/Rig")
        skeleton = UsdSkel.Skeleton.Define(stage, f"{root}/Rig/Skeleton")
        anim = UsdSkel.Animation.Define(stage, f"{root}/Rig/Anim")
        tokens = Vt.TokenArray(paths)
        skeleton.CreateJointsAttr(tokens)
        skeleton.CreateJointNamesAttr(Vt.TokenArray([str(n) for n in names]))
        skeleton.CreateBindTransformsAttr(Vt.Matrix4dArray.FromNumpy(_usd_matrices(self.rest)))
        skeleton.CreateRestTransformsAttr(Vt.Matrix4dArray.FromNumpy(
            _usd_matrices(local_transforms(self.rest, self.parents))))
        UsdSkel.BindingAPI.Apply(skeleton.GetPrim()).CreateAnimationSourceRel().SetTargets(
            [anim.GetPath()])
        UsdSkel.BindingAPI.Apply(skel_root.GetPrim()).CreateSkeletonRel().SetTargets(
            [skeleton.GetPath()])
        anim.CreateJointsAttr(tokens)
        self._translations = anim.CreateTranslationsAttr()
        self._rotations = anim.CreateRotationsAttr()
        anim.CreateScalesAttr(Vt.Vec3hArray.FromNumpy(np.ones((len(paths), 3), np.float16)))
        self._bounds = np.empty((2, 3), np.float32)

    def write(self, points: np.ndarray, world: np.ndarray) -> None:
        """Append one frame: points (n, 3) deformed vertices; world (b, 3, 4) joint rigid maps."""
        self._check_open()
        Vt, Usd = self._Vt, self._Usd
        self.num_frames += 1
        time = Usd.TimeCode(self.num_frames)
        if self._to_object is not None:
            np.matmul(points, self._to_object[:, :3].T, out=self._local, casting="same_kind")
            self._local += self._to_object[:, 3]
            pts = self._local
        else:
            pts = np.ascontiguousarray(points, np.float32)
        if not np.isfinite(pts).all():
            raise ExportError(self.path, f"frame {self.num_frames}: points are not finite")
        self._points.Set(Vt.Vec3fArray.FromNumpy(pts), time)
        if self._normals is not None:
            self._normals_attr.Set(Vt.Vec3fArray.FromNumpy(self._normals(pts)), time)
        np.min(pts, axis=0, out=self._bounds[0])
        np.max(pts, axis=0, out=self._bounds[1])
        self._extent.Set(Vt.Vec3fArray.FromNumpy(self._bounds), time)
        local = local_transforms(compose(np.asarray(world, np.float64), self.rest), self.parents)
        self._translations.Set(Vt.Vec3fArray.FromNumpy(
            np.ascontiguousarray(local[:, :, 3], np.float32)), time)
        self._rotations.Set(Vt.QuatfArray.FromNumpy(
            matrix_to_quaternion(local[:, :, :3]).astype(np.float32)), time)
        if self.save_every and self.num_frames % self.save_every == 0:
            self._save()

    def _save(self) -> None:
        try:
            saved = self.stage.GetRootLayer().Save()
        except self._Tf.ErrorException as e:
            raise ExportError(self.path, f"cannot write USD: {_usd_reason(e)}") from e
        if not saved or not self.layer.exists():
            raise ExportError(self.path, "cannot write USD: the layer was not saved (disk full?)")

    def _drop_package(self) -> None:
        """Remove a .usdz's temporary folder (its layer and textures)."""
        if self._package is not None:
            shutil.rmtree(self._package[0], ignore_errors=True)
            self._package = None

    def close(self) -> None:
        """Set the end time code, save and release the stage (a .usdz: package the layer and its
        textures into path). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.num_frames == 0:
                raise ExportError(self.path, "no frames to write")
            self.stage.SetEndTimeCode(self.num_frames)
            self._save()
            if self._package is not None:
                from pxr import Sdf, UsdUtils

                self.stage = None
                try:
                    packed = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(self.layer)), str(self.path))
                except self._Tf.ErrorException as e:
                    raise ExportError(self.path, f"cannot write the .usdz: {_usd_reason(e)}") from e
                if not packed or not self.path.exists():
                    raise ExportError(self.path, "cannot write the .usdz: the package was not written "
                                                 "(disk full?)")
        finally:
            self.stage = self._points = self._extent = None
            self._translations = self._rotations = None
            self._drop_package()

    def abort(self) -> None:
        """Release the stage without saving more."""
        self._closed = True
        self.stage = self._points = self._extent = None
        self._translations = self._rotations = None
        self._drop_package()


class _SmoothNormals:
    """Per-frame unit vertex normals, area weighted, shared by the copies of a welded vertex
    (so a UV seam shades smooth). F: (f, 3) triangles; weld: (n,) welded index of each vertex."""

    def __init__(self, F: np.ndarray, weld: np.ndarray):
        from scipy.sparse import csr_matrix

        self.F = np.asarray(F, np.int64)
        self.weld = np.asarray(weld, np.int64)
        k = int(self.weld.max()) + 1 if len(self.weld) else 0
        rows = self.weld[self.F].reshape(-1)
        cols = np.repeat(np.arange(len(self.F)), 3)
        self.gather = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(k, len(self.F)))

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) float32 normals of points (n, 3) (+Y where no triangle gives one)."""
        P = np.asarray(points, np.float64)
        F = self.F
        cross = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
        N = (self.gather @ cross)[self.weld]
        length = np.linalg.norm(N, axis=1, keepdims=True)
        N = np.where(length > 0, N / np.where(length > 0, length, 1.0), [0.0, 1.0, 0.0])
        return N.astype(np.float32)


def _xform_ops(xform, node) -> None:
    """A node's local transform as written: translate/orient/scale ops, or one matrix op."""
    from pxr import Gf

    if node.matrix is not None:
        xform.AddTransformOp().Set(Gf.Matrix4d(np.ascontiguousarray(node.local.T).tolist()))
        return
    if node.translation is not None:
        xform.AddTranslateOp().Set(Gf.Vec3d(*node.translation))
    if node.rotation is not None:
        x, y, z, w = node.rotation
        xform.AddOrientOp().Set(Gf.Quatf(float(w), float(x), float(y), float(z)))
    if node.scale is not None:
        xform.AddScaleOp().Set(Gf.Vec3f(*node.scale))


def _source_xforms(stage, root: str, source) -> tuple[str, np.ndarray | None]:
    """Xforms of the file's nodes that are not joints, not under one and not the skinned mesh
    node (unless it has children); returns (the Mesh's path: under the armature's Xform, named
    as the mesh node; the (3, 4) map of model-frame points into its space, None: identity)."""
    from pxr import Gf, UsdGeom

    nodes = source.nodes
    taken: dict[str, set] = {}

    def child(above: str, base: str) -> str:
        """A path under ``above`` named ``base`` (made unique among its siblings)."""
        siblings = taken.setdefault(above, {"Mesh", "Rig", "Materials"} if above == root else set())
        name, n = base, 2
        while name in siblings:
            name, n = f"{base}_{n}", n + 1
        siblings.add(name)
        return f"{above}/{name}"

    def static(i: int) -> bool:
        k = i
        while k >= 0:
            if nodes[k].joint >= 0 or (k == i and nodes[i].mesh >= 0 and not nodes[i].children):
                return False
            k = nodes[k].parent
        return True

    paths: dict[int, str] = {}
    for i in range(len(nodes)):
        chain = []
        k = i
        while k >= 0 and k not in paths and static(k):  # up to a placed node or the root
            chain.append(k)
            k = nodes[k].parent
        if not static(i):
            continue
        for k in reversed(chain):
            parent = nodes[k].parent
            paths[k] = child(root if parent < 0 else paths[parent], safe_name(nodes[k].name or f"node{k}"))
            _xform_ops(UsdGeom.Xform.Define(stage, paths[k]), nodes[k])
    mesh_node = nodes[source.mesh_nodes[0]]
    name = safe_name(mesh_node.name or source.mesh_names[0] or "Mesh")
    world = source.object_world
    to_object = None if np.allclose(world, np.eye(4), atol=0) else np.linalg.inv(world)[:3]
    if source.armature in paths:
        above = paths[source.armature]
    elif to_object is None:
        above = root
    else:  # the armature node sits under a joint: its world as one matrix op
        above = child(root, f"{name}_space")
        UsdGeom.Xform.Define(stage, above).AddTransformOp().Set(
            Gf.Matrix4d(np.ascontiguousarray(world.T).tolist()))
    return child(above, name), to_object


def _primvars(mesh, source) -> None:
    """The file's UV sets (st, st<k>; t = 1 - v), vertex colours (displayColor/displayOpacity
    from COLOR_0, COLOR_<k>) on the mesh, per vertex."""
    from pxr import Sdf, UsdGeom, Vt

    api = UsdGeom.PrimvarsAPI(mesh)
    for name, values in sorted(source.attributes.items()):
        if name.startswith("TEXCOORD_"):
            st = np.ascontiguousarray(np.column_stack([values[:, 0], 1.0 - values[:, 1]]), np.float32)
            api.CreatePrimvar(primvar_name(int(name.split("_")[1])), Sdf.ValueTypeNames.TexCoord2fArray,
                              UsdGeom.Tokens.vertex).Set(Vt.Vec2fArray.FromNumpy(st))
        elif name == "COLOR_0":
            rgb = np.ascontiguousarray(values[:, :3], np.float32)
            mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex).Set(Vt.Vec3fArray.FromNumpy(rgb))
            if values.shape[1] == 4:
                mesh.CreateDisplayOpacityPrimvar(UsdGeom.Tokens.vertex).Set(
                    Vt.FloatArray.FromNumpy(np.ascontiguousarray(values[:, 3], np.float32)))
        elif name.startswith("COLOR_"):
            four = values.shape[1] == 4
            kind = Sdf.ValueTypeNames.Color4fArray if four else Sdf.ValueTypeNames.Color3fArray
            array = (Vt.Vec4fArray if four else Vt.Vec3fArray).FromNumpy(
                np.ascontiguousarray(values, np.float32))
            api.CreatePrimvar(name, kind, UsdGeom.Tokens.vertex).Set(array)


def _bind(mesh, source, materials: list) -> None:
    """Bind each primitive's material: the whole mesh when one primitive, else a GeomSubset of
    each primitive's triangles."""
    from pxr import UsdGeom, UsdShade, Vt

    prims = [p for group in source.primitives for p in group]
    if not materials:
        return
    if len(prims) == 1:
        if prims[0].material is not None:
            UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(materials[prims[0].material])
        return
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    first = 0
    for k, prim in enumerate(prims):
        count = len(prim.indices) // 3
        faces = np.arange(first, first + count, dtype=np.int32)
        first += count
        if prim.material is None:
            continue
        subset = UsdGeom.Subset.Define(mesh.GetPrim().GetStage(), mesh.GetPath().AppendChild(f"primitive{k}"))
        subset.CreateElementTypeAttr(UsdGeom.Tokens.face)
        subset.CreateFamilyNameAttr(UsdShade.Tokens.materialBind)
        subset.CreateIndicesAttr(Vt.IntArray.FromNumpy(faces))
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(materials[prim.material])
