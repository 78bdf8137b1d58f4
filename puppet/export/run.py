"""Exporting one take: resample, solve every frame, write every asked format in one pass.

    report = export_take(rig, reader, Outputs(gltf="anim.glb", pc2="mesh.pc2"), fps=24, up="z")

Frame k (k = 1..N) is the take at ``(k − 1) / fps`` seconds after its first reading (see
``puppet.export.resample``): frame 1 is the first reading in every format (glTF key time k/fps,
USD time code k, PC2 start frame 1, BVH's first frame, which Blender's importer puts on frame 1).
Every output is written to a temporary file next to it and renamed when all are complete
(``puppet.atomic``): a failed export leaves no half file and keeps an existing good one.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet.atomic import atomic_output, check_output
from puppet.export.bvh import BvhWriter
from puppet.export.errors import ExportError
from puppet.export.gltf import GltfWriter
from puppet.export.joint_transforms import JointTransforms
from puppet.export.names import safe_names
from puppet.export.pc2 import Pc2Writer
from puppet.export.resample import Resampler, check_fps
from puppet.export.source_order import SourceOrder

FORMATS = ("gltf", "usd", "pc2", "bvh")
UP_AXES = ("y", "z")
FIRST_FRAME = 1  # frame number of the take's first reading, in every format
SUFFIXES = {"gltf": (".glb",), "usd": (".usdc", ".usda", ".usd")}  # the format follows the name


@dataclass
class Outputs:
    """Files to write; None skips a format."""

    gltf: str | Path | None = None
    usd: str | Path | None = None
    pc2: str | Path | None = None
    bvh: str | Path | None = None

    def items(self) -> list[tuple[str, Path]]:
        return [(f, Path(getattr(self, f))) for f in FORMATS if getattr(self, f)]


@dataclass
class ExportReport:
    """What an export wrote.

    frames: frames per file; fps: their rate; take_seconds: first to last reading.
    files: {format: (path, bytes)}. renamed: {joint name: safe name} for BVH/USD joints.
    lbs_rms_pct, lbs_max_pct: linear blend skinning of the glTF's skeleton with the file's own
        weights against the FAST mesh, over every vertex of every frame, % of the rest bounding
        box diagonal (None without --gltf).
    bvh_stretch_max_pct: how far the solve moves joints off their rest distance to their parent:
        the largest distance between a pivot and where rotations and rest offsets alone would put
        it, % of the diagonal (None without --bvh). The BVH carries a position channel on every
        joint for this, so its joints land on the solved pivots all the same.
    seconds: wall time of the export.
    """

    frames: int
    fps: float
    take_seconds: float
    files: dict[str, tuple[Path, int]] = field(default_factory=dict)
    renamed: dict[str, str] = field(default_factory=dict)
    lbs_rms_pct: float | None = None
    lbs_max_pct: float | None = None
    bvh_stretch_max_pct: float | None = None
    seconds: float = 0.0

    def as_dict(self) -> dict:
        return {"frames": self.frames, "fps": self.fps, "first_frame": FIRST_FRAME,
                "take_seconds": round(self.take_seconds, 6),
                "files": {f: {"path": str(p), "bytes": b} for f, (p, b) in self.files.items()},
                "renamed_joints": dict(self.renamed), "lbs_rms_pct": self.lbs_rms_pct,
                "lbs_max_pct": self.lbs_max_pct, "bvh_stretch_max_pct": self.bvh_stretch_max_pct,
                "seconds": round(self.seconds, 3)}

    def text(self) -> str:
        lines = [f"frames: {self.frames} at {self.fps:g} fps (frame {FIRST_FRAME} = the first "
                 f"reading; take {self.take_seconds:.3f} s)"]
        for fmt, (path, size) in self.files.items():
            lines.append(f"{fmt}: {path} ({size} bytes)")
        if self.lbs_rms_pct is not None:
            lines.append(f"gltf skeleton vs FAST mesh (LBS with the file's weights): RMS "
                         f"{self.lbs_rms_pct:.3f} %, max {self.lbs_max_pct:.3f} % of the bbox diagonal")
        if self.bvh_stretch_max_pct is not None:
            lines.append(f"bvh: every joint has position channels (the solve moves pivots up to "
                         f"{self.bvh_stretch_max_pct:.3f} % of the bbox diagonal off rest offsets)")
        for old, new in self.renamed.items():
            lines.append(f"joint renamed for BVH/USD: {old!r} -> {new!r}")
        return "\n".join(lines)


@contextlib.contextmanager
def _blame(target: Path, fmt: str) -> Iterator[None]:
    """Errors while writing a temporary file are reported against the user's target path."""
    try:
        yield
    except ExportError as e:
        raise ExportError(target, e.reason) from None
    except OSError as e:
        raise ExportError(target, f"cannot write the {fmt} file: {e.strerror or e}; nothing was "
                                  "written (an existing file there is untouched)") from None


def _abort(writer) -> None:
    """Release a writer on a failed export (its temporary file is removed right after)."""
    with contextlib.suppress(OSError):  # e.g. a full disk again while closing: the file goes anyway
        writer.abort()


def _bvh_skeleton(rig):
    sk = rig.skeleton
    roots = np.flatnonzero(sk.parents < 0)
    if len(roots) != 1:
        raise ExportError("--bvh", f"a BVH file has one root joint; the rig's skeleton has "
                                   f"{len(roots)}: {[sk.names[r] for r in roots]}")
    offsets = sk.heads - np.where(sk.parents[:, None] >= 0, sk.heads[sk.parents], 0.0)
    return offsets, sk.tails - sk.heads


def export_take(rig, reader, outputs: Outputs, *, fps: float = 30.0, up: str = "y",
                iterations: int = 8, influences: int = 4, meters_per_unit: float = 1.0,
                progress: Callable[[int, int], None] | None = None,
                precompute=None) -> ExportReport:
    """Export a take (TakeReader) solved on ``rig`` into every file named in ``outputs``.

    fps:        output frames per second (> 0); frames are resampled from the reading times.
    up:         'y' (the model's frame) or 'z' (Blender: (x, y, z) -> (x, −z, y)), PC2 only:
                glTF is Y-up by its spec, USD says its upAxis, BVH importers convert Y-up.
    iterations: FAST iterations per frame. influences: glTF weights per vertex (multiple of 4).
    progress:   called with (frames done, frames in all) after each frame.
    precompute: a shared ``puppet.loop.RigPrecompute`` of ``rig`` (batch), None: built here.
    Raises ExportError (or the take's TakeRigMismatch) naming the file at fault.
    """
    start = time.monotonic()
    fps = check_fps(fps)
    if up not in UP_AXES:
        raise ExportError("--up", f"up axis must be one of {UP_AXES}, got {up!r}")
    items = outputs.items()
    if not items:
        raise ExportError("export", "nothing to write: give --gltf, --usd, --pc2 and/or --bvh FILE")
    take_path = Path(reader.path)
    inputs = [take_path] + ([Path(rig.path)] if getattr(rig, "path", None) else [])
    seen: dict[Path, str] = {}
    for fmt, target in items:
        key = target.resolve()
        if key in seen:
            raise ExportError(target, f"given for both --{seen[key]} and --{fmt}")
        seen[key] = fmt
        if fmt in SUFFIXES and target.suffix.lower() not in SUFFIXES[fmt]:
            raise ExportError(target, f"--{fmt} files are named *{' or *'.join(SUFFIXES[fmt])}")
        check_output(target, inputs=inputs)
    ids = [int(i) for i in rig.servo_map.ids]
    if len(reader) == 0:
        raise ExportError(take_path, "the take holds no readings")
    reader.check_rig(ids, dict(rig.servo_map.models), rig_name=rig.name)
    frames = Resampler(*reader.arrays(ids=ids), np.asarray(ids), fps, source=take_path)
    sk = rig.skeleton
    if "bvh" in dict(items):
        offsets, end_sites = _bvh_skeleton(rig)

    from puppet.loop import Pipeline  # the solver's native module: only when exporting

    order = SourceOrder(rig)
    V_out = order.take(rig.V)
    diagonal = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0))) or 1.0
    safe, renamed = safe_names(sk.names)
    report = ExportReport(frames=len(frames), fps=fps,
                          take_seconds=(frames.t_ns[-1] - frames.t_ns[0]) * 1e-9)
    with contextlib.ExitStack() as stack:
        pipeline = stack.enter_context(Pipeline(rig, render=False, iterations=iterations,
                                                precompute=precompute))
        writers: dict[str, object] = {}
        targets = dict(items)
        try:
            for fmt, target in items:
                temporary = stack.enter_context(atomic_output(target, inputs=inputs))
                with _blame(target, fmt):
                    if fmt == "gltf":
                        writers[fmt] = GltfWriter(temporary, names=sk.names, parents=sk.parents,
                                                  heads=sk.heads, frames=sk.frames, V=V_out,
                                                  F=order.F, W=order.take(rig.W), fps=fps,
                                                  influences=influences, name=rig.name)
                    elif fmt == "usd":
                        from puppet.export.usd import UsdWriter

                        writers[fmt] = UsdWriter(temporary, names=sk.names, parents=sk.parents,
                                                 heads=sk.heads, frames=sk.frames, V=V_out,
                                                 F=order.F, fps=fps, name=rig.name,
                                                 meters_per_unit=meters_per_unit)
                        renamed.update(writers[fmt].renamed)
                    elif fmt == "pc2":
                        writers[fmt] = Pc2Writer(temporary, order.n_out,
                                                 start_frame=float(FIRST_FRAME), sample_rate=1.0)
                    else:
                        writers[fmt] = BvhWriter(temporary, names=safe, parents=sk.parents,
                                                 offsets=offsets, end_sites=end_sites,
                                                 frame_time=1.0 / fps, positions="all")
            _solve_and_write(pipeline, frames, writers, targets, order, up, diagonal, report,
                             progress)
        except BaseException:
            for writer in writers.values():
                _abort(writer)
            raise
        for fmt, writer in writers.items():  # complete files; the renames follow as the stack unwinds
            with _blame(targets[fmt], fmt):
                writer.close()
    for fmt, target in items:
        report.files[fmt] = (target, target.stat().st_size)
    if "bvh" in targets or "usd" in targets:
        report.renamed = renamed
    report.seconds = time.monotonic() - start
    return report


def _solve_and_write(pipeline, frames: Resampler, writers: dict, targets: dict, order: SourceOrder,
                     up: str, diagonal: float, report: ExportReport, progress) -> None:
    """The per-frame loop: solve, deform (V' = M T), joint transforms, one record per writer."""
    rig = pipeline.rig
    sk = rig.skeleton
    T = np.empty(pipeline.T.shape, np.float64)
    deformed = np.empty((len(rig.V), 3))
    points = np.empty((order.n_out, 3))
    pc2_points = np.empty((order.n_out, 3), np.float32)
    joints = JointTransforms(sk.heads)
    rotations = np.empty((sk.bone_count, 3, 3))
    parents = sk.parents
    offsets = sk.heads - np.where(parents[:, None] >= 0, sk.heads[parents], 0.0)
    chain = np.empty((sk.bone_count, 3))
    local = np.empty((sk.bone_count, 3))
    gltf, usd, pc2, bvh = (writers.get(f) for f in FORMATS)
    need_mesh = gltf is not None or usd is not None or pc2 is not None
    M = pipeline.model.lbs_matrix() if need_mesh else None  # (n, 4m) float64: V' = M T
    skinned = np.empty((order.n_out, 3))
    squares, count, worst, drift = 0.0, 0, 0.0, 0.0
    for f, reading in enumerate(frames):
        pipeline.solve(reading)
        joints.update(pipeline.T)
        if need_mesh:
            T[...] = pipeline.T
            np.matmul(M, T, out=deformed)
            order.take(deformed, out=points)
        if pc2 is not None:
            if up == "z":
                pc2_points[:, 0] = points[:, 0]
                pc2_points[:, 1] = -points[:, 2]
                pc2_points[:, 2] = points[:, 1]
            else:
                pc2_points[...] = points
            with _blame(targets["pc2"], "pc2"):
                pc2.write(pc2_points)
        if usd is not None:
            with _blame(targets["usd"], "usd"):
                usd.write(points, joints.world)
        if gltf is not None:
            gltf.write(joints.world)
            gltf.skin(joints.world, out=skinned)
            skinned -= points
            error = np.sqrt(np.einsum("ij,ij->i", skinned, skinned))
            squares += float(np.dot(error, error))
            count += len(error)
            worst = max(worst, float(error.max()))
        if bvh is not None:
            R, c = joints.rotation, joints.pivot
            rotations[...] = R
            local[...] = c
            has = parents >= 0
            Rp = np.swapaxes(R[parents[has]], 1, 2)
            rotations[has] = Rp @ R[has]                                   # parent-relative
            local[has] = np.einsum("bij,bj->bi", Rp, c[has] - c[parents[has]])  # in parent frame
            for j, p in enumerate(parents):  # what a BVH reader rebuilds: rest offsets, no stretch
                chain[j] = c[j] if p < 0 else chain[p] + R[p] @ offsets[j]
            drift = max(drift, float(np.linalg.norm(chain - c, axis=1).max()))
            with _blame(targets["bvh"], "bvh"):
                bvh.write(rotations, positions=local)
        if progress is not None:
            progress(f + 1, len(frames))
    if gltf is not None:
        report.lbs_rms_pct = 100.0 * float(np.sqrt(squares / max(count, 1))) / diagonal
        report.lbs_max_pct = 100.0 * worst / diagonal
    if bvh is not None:
        report.bvh_stretch_max_pct = 100.0 * drift / diagonal
