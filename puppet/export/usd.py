"""USD (.usdc/.usda/.usd) with usd-core: the exact deformed mesh and the animated skeleton.

Stage layout (default prim ``/<name>``):
  /<name>            Xform
  /<name>/Mesh       Mesh: faceVertexCounts/Indices, rest points as the default value, and one
                     points (and extent) time sample per frame: the FAST result itself.
  /<name>/Rig        SkelRoot
  /<name>/Rig/Skeleton  Skeleton: every joint (BVH-safe names as paths), bind and rest transforms;
                     skel:animationSource -> Anim. No mesh is bound to it (the mesh's points are
                     already deformed), so nothing is skinned twice.
  /<name>/Rig/Anim   SkelAnimation: translations, rotations (time-sampled), scales (ones).
Stage metadata: upAxis, metersPerUnit, timeCodesPerSecond = framesPerSecond = fps,
startTimeCode 1, endTimeCode N: frame k is time code k, frame 1 the take's first reading.
The layer is saved every ``save_every`` frames, so memory stays bounded on long takes.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from puppet.export.errors import ExportError
from puppet.export.joint_transforms import (compose, local_transforms, matrix_to_quaternion,
                                            rest_globals)
from puppet.export.names import safe_names
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

    path:     output file (.usdc binary, .usda text or .usd).
    names:    b joint names; parents (b,) int; heads (b, 3) rest pivots; frames (b, 3, 3) rest frames.
    V:        (n, 3) rest vertices (output order); F (f, 3) triangles into V.
    fps:      frames per second (timeCodesPerSecond).
    up:       'Y' or 'Z': the stage's upAxis (the data is written as given).
    meters_per_unit: the stage's metersPerUnit (model units in metres).
    Fields: joint_paths (b,) the Skeleton's joint tokens; renamed {name: safe name}.
    """

    close_on_error = False  # an error inside `with` releases the stage without saving more

    def __init__(self, path, *, names, parents, heads, frames, V, F, fps: float, up: str = "Y",
                 meters_per_unit: float = 1.0, name: str = "character", save_every: int = 64):
        Tf, Usd, UsdGeom, UsdSkel, Vt = _usd()
        self._Tf, self._Vt, self._Usd = Tf, Vt, Usd
        self.path = Path(path)
        if up not in UP_AXES:
            raise ExportError(self.path, f"up axis must be one of {UP_AXES}, got {up!r}")
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
            stage = Usd.Stage.CreateNew(str(self.path))
        except Tf.ErrorException as e:
            raise ExportError(self.path, f"cannot create USD stage: {_usd_reason(e)}") from e
        self.stage = stage
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        stage.SetStartTimeCode(1)
        stage.SetEndTimeCode(1)
        top = UsdGeom.Xform.Define(stage, root)
        stage.SetDefaultPrim(top.GetPrim())

        V = np.asarray(V, np.float32)
        F = np.asarray(F, np.int32)
        mesh = UsdGeom.Mesh.Define(stage, f"{root}/Mesh")
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(F.reshape(-1))))
        self._points = mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(V))
        self._extent = mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([V.min(0), V.max(0)])))

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
        pts = np.ascontiguousarray(points, np.float32)
        if not np.isfinite(pts).all():
            raise ExportError(self.path, f"frame {self.num_frames}: points are not finite")
        self._points.Set(Vt.Vec3fArray.FromNumpy(pts), time)
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
        if not saved or not self.path.exists():
            raise ExportError(self.path, "cannot write USD: the layer was not saved (disk full?)")

    def close(self) -> None:
        """Set the end time code, save and release the stage. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.num_frames == 0:
                raise ExportError(self.path, "no frames to write")
            self.stage.SetEndTimeCode(self.num_frames)
            self._save()
        finally:
            self.stage = self._points = self._extent = None
            self._translations = self._rotations = None

    def abort(self) -> None:
        """Release the stage without saving more."""
        self._closed = True
        self.stage = self._points = self._extent = None
        self._translations = self._rotations = None

