"""Exporting one take: its frames, solved once each, written into every asked format.

    report = export_take(rig, reader, Outputs(gltf="anim.glb", pc2="mesh.pc2"), fps=24, up="z")

Frame k (k = 1..N) is frame k − 1 of ``puppet.take.Playback`` at fps, the one take-to-frames
rule (``play`` and ``batch``'s video show the same frames; gaps over MAX_GAP_S cut the same):
frame 1 is the first reading in every format (glTF key time k/fps, USD time code k, PC2 start
frame 1, BVH's first frame, which Blender's importer puts on frame 1). ``ExportWriters`` is the
per-frame sink of the solved pipeline (``run_frames``' on_frame): ``export_take`` runs it on a
solve-only pipeline, ``puppet.replay.play_take`` beside a video (batch: one solve for every
format). Every output is written to a temporary file next to it and renamed when all are
complete (``puppet.atomic``): a failed export leaves no half file and keeps an existing good one.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from puppet import limits
from puppet.atomic import atomic_output, check_distinct, check_output
from puppet.export.bvh import BvhWriter, mesh_end_sites
from puppet.export.errors import ExportError
from puppet.export.gltf import GltfWriter
from puppet.export.joint_transforms import JointTransforms
from puppet.export.names import safe_names
from puppet.export.pc2 import Pc2Writer
from puppet.export.source_order import SourceOrder
from puppet.export.sync import sync_fields
from puppet.take.playback import MAX_GAP_S, Playback, check_rate

FORMATS = ("gltf", "usd", "pc2", "bvh")
UP_AXES = ("y", "z")
SPACES = ("object", "model")  # where point caches' points are: see point_space()
FIRST_FRAME = 1  # frame number of the take's first reading, in every format
KINDS = {"gltf": "glb", "usd": "usd", "pc2": "pc2", "bvh": "bvh"}  # puppet.atomic's file kinds
SUFFIXES = {"gltf": (".glb",), "usd": (".usdc", ".usda", ".usd", ".usdz")}  # the format follows the name


@dataclass
class Outputs:
    """Files to write; None skips a format. force: an existing file of another kind may be
    replaced (``puppet.atomic``'s rule; an input never)."""

    gltf: str | Path | None = None
    usd: str | Path | None = None
    pc2: str | Path | None = None
    bvh: str | Path | None = None
    force: bool = False

    def items(self) -> list[tuple[str, Path]]:
        return [(f, Path(getattr(self, f))) for f in FORMATS if getattr(self, f)]


@dataclass
class ExportReport:
    """What an export wrote.

    frames: frames per file; fps: their rate; take_seconds: first to last reading, as recorded;
    cuts: the gaps between readings cut to MAX_GAP_S (puppet.take.Cut), the same in every output.
    files: {format: (path, bytes)}. renamed: {format: {joint name: its name in that file}} for
        the joints a format's naming rule changed (``puppet.export.names``: BVH, USD paths).
    lbs_rms_pct, lbs_max_pct: linear blend skinning of the glTF's skeleton with the file's own
        weights against the FAST mesh, over every vertex of every frame, % of the rest bounding
        box diagonal (None without --gltf).
    bvh_stretch_max_pct: how far the solve moves joints off their rest distance to their parent:
        the largest distance between a pivot and where rotations and rest offsets alone would put
        it, % of the diagonal (None without --bvh). The BVH carries a position channel on every
        joint for this, so its joints land on the solved pivots all the same.
    pc2_space: where the PC2's points are: 'model' or 'object' (the mesh object's local space,
        ``point_space``); None without --pc2.
    warnings: what of the character file could not be carried (a missing image file...), in
        words naming the file.
    keys: None (a glTF key on every frame) or the glTF's key reduction: {"rotation_deg",
        "translation_units": the tolerances, "kept": keys written, "every_frame": keys a key on
        every frame would take, "kept_pct", "joints": {joint name: {"translation": keys,
        "rotation": keys}}, "key_poses": a shot's key poses, each a key on every channel (0 for a
        take)}.
    seconds: wall time of the export.
    """

    frames: int
    fps: float
    take_seconds: float
    cuts: list = field(default_factory=list)
    files: dict[str, tuple[Path, int]] = field(default_factory=dict)
    renamed: dict[str, dict[str, str]] = field(default_factory=dict)
    lbs_rms_pct: float | None = None
    lbs_max_pct: float | None = None
    bvh_stretch_max_pct: float | None = None
    pc2_space: str | None = None
    warnings: list[str] = field(default_factory=list)
    keys: dict | None = None
    seconds: float = 0.0

    def as_dict(self) -> dict:
        return {"frames": self.frames, "fps": self.fps, "first_frame": FIRST_FRAME,
                "take_seconds": round(self.take_seconds, 6),
                "gaps_cut": [{"at_s": c.at_ns * 1e-9, "gap_s": c.gap_ns * 1e-9} for c in self.cuts],
                "files": {f: {"path": str(p), "bytes": b} for f, (p, b) in self.files.items()},
                "renamed_joints": {f: dict(m) for f, m in self.renamed.items()},
                "keys": self.keys, "lbs_rms_pct": self.lbs_rms_pct, "lbs_max_pct": self.lbs_max_pct,
                "bvh_stretch_max_pct": self.bvh_stretch_max_pct,
                "pc2_space": self.pc2_space, "warnings": list(self.warnings),
                "seconds": round(self.seconds, 3)}

    def text(self) -> str:
        lines = [f"frames: {self.frames} at {self.fps:g} fps (frame {FIRST_FRAME} = the first "
                 f"reading; take {self.take_seconds:.3f} s)"]
        if self.cuts:
            lines.append(f"gaps cut to {MAX_GAP_S:g} s: {len(self.cuts)} (the longest "
                         f"{max(c.gap_ns for c in self.cuts) * 1e-9:.3f} s)")
        for fmt, (path, size) in self.files.items():
            lines.append(f"{fmt}: {path} ({size} bytes)")
        if self.pc2_space == "object":
            lines.append("pc2: points in the mesh object's local space (where Blender's glTF importer "
                         "puts the character's mesh; --space model: the model frame)")
        if self.lbs_rms_pct is not None:
            lines.append(f"gltf skeleton vs FAST mesh (LBS with the file's weights): RMS "
                         f"{self.lbs_rms_pct:.3f} %, max {self.lbs_max_pct:.3f} % of the bbox diagonal")
        if self.bvh_stretch_max_pct is not None:
            lines.append(f"bvh: every joint has position channels (the solve moves pivots up to "
                         f"{self.bvh_stretch_max_pct:.3f} % of the bbox diagonal off rest offsets)")
        if self.keys is not None:
            k = self.keys
            lines.append(f"gltf keys within {k['rotation_deg']:g}° and {k['translation_units']:.4g} "
                         f"model units: {k['kept']} of {k['every_frame']} ({k['kept_pct']:.1f} %)"
                         + (f"; every channel keyed at the shot's {k['key_poses']} key poses"
                            if k["key_poses"] else ""))
            lines.extend(f"  {name}: {c['rotation']} rotation, {c['translation']} translation"
                         for name, c in k["joints"].items())
        for fmt, renamed in self.renamed.items():
            for old, new in renamed.items():
                lines.append(f"{fmt}: joint {old!r} is named {new!r} (the format's naming rule)")
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
    return offsets, mesh_end_sites(sk.heads, sk.tails, sk.frames, sk.parents, rig.V, rig.W)


def point_space(rig, space: str = "object") -> np.ndarray | None:
    """(3, 4) map from model-frame points to the space a point cache is written in, or None
    where that is the model frame itself.

    space 'object': the local space of the mesh object that Blender's glTF importer makes from
    the character file (``SourceScene.object_world``: the armature object's, which the skinned mesh
    is parented to with an identity transform), so the Mesh Cache modifier lands the points on a
    moved, turned or scaled character. 'model': the model frame (the file's world). The two
    are the same for a character that is not glTF or whose armature has no transform.
    """
    if space not in SPACES:
        raise ExportError("--space", f"must be one of {SPACES}, got {space!r}")
    source = rig.source
    if space == "model" or source is None or np.allclose(source.object_world, np.eye(4), atol=0):
        return None
    return np.linalg.inv(source.object_world)[:3]


def default_keys_units(rig, degrees: float) -> float:
    """Translation tolerance (model units) that goes with a rotation tolerance of ``degrees``:
    how far that turn moves a point one rest bounding-box diagonal from its pivot
    (radians(degrees) × diagonal; 0.5° on the built-in critter: 0.016 units, 0.87 % of it)."""
    diagonal = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0))) or 1.0
    return math.radians(degrees) * diagonal


def _key_tolerances(rig, outputs: Outputs, keys, keys_units) -> tuple[float | None, float | None]:
    """(degrees, model units) of glTF key reduction, or (None, None) for a key on every frame;
    each checked against its Range in puppet.limits, errors naming the option."""
    if keys is None:
        if keys_units is not None:
            raise ExportError("--keys-units", "needs --keys (the rotation tolerance, degrees)")
        return None, None
    problem = limits.KEYS_DEG.problem(keys)
    if problem:
        raise ExportError("--keys", problem)
    if not outputs.gltf:
        raise ExportError("--keys", "reduces the glTF's keys: give --gltf FILE (BVH, USD and PC2 "
                                    "keep every frame)")
    if keys_units is None:
        keys_units = default_keys_units(rig, keys)
    problem = limits.KEYS_UNITS.problem(keys_units)
    if problem:
        raise ExportError("--keys-units", problem)
    return float(keys), float(keys_units)


def check_fps(fps, where: str = "--fps") -> float:
    """fps as a float, or an error naming ``where`` unless it is a finite number > 0."""
    return check_rate(fps, "frames per second", where)


def export_take(rig, reader, outputs: Outputs, *, fps: float = 30.0, up: str = "y",
                space: str = "object", iterations: int = 8, influences: int = 4,
                meters_per_unit: float = 1.0, keys: float | None = None,
                keys_units: float | None = None,
                progress: Callable[[int, int], None] | None = None,
                precompute=None, sound=None, clip=None, layers=None) -> ExportReport:
    """Export a take (TakeReader) solved on ``rig`` into every file named in ``outputs``.

    fps:        output frames per second (> 0); frames by ``puppet.take.Playback``.
    up:         'y' (the model's frame) or 'z' (Blender: (x, y, z) -> (x, −z, y)), PC2 only:
                glTF is Y-up by its spec, USD says its upAxis, BVH importers convert Y-up.
    space:      'object' or 'model': the space of the PC2 points (``point_space``), before ``up``.
    iterations: FAST iterations per frame. influences: glTF weights per vertex (multiple of 4).
    keys:       None: a glTF key on every frame; else the glTF's rotation keys reproduce each
                joint's solved curve within ``keys`` degrees, its translation keys within
                ``keys_units`` model units (None: ``default_keys_units``), LINEAR
                (``puppet.export.key_reduction``). BVH, USD and PC2 stay per frame.
    progress:   called with (frames done, frames in all) after each frame.
    precompute: a shared ``puppet.loop.RigPrecompute`` of ``rig`` (batch), None: built here.
    sound:      a ``puppet.take.sync.SoundRef`` the files name (None: the take's own, if any).
    clip:       (in_s, out_s, loop): only that segment of the take (``Playback.clip``; a loop
                with its seam blended in solve space); None: the whole take.
    layers:     a layered take's ``puppet.take.layers.LayerOptions`` (mute, solo, punch; None:
                as recorded).
    Raises ExportError (or the take's TakeRigMismatch) naming the file at fault.
    """
    start = time.monotonic()
    frames = take_frames(rig, reader, fps, clip=clip, layers=layers)
    with ExportWriters(rig, reader, outputs, frames, up=up, space=space, influences=influences,
                       meters_per_unit=meters_per_unit, keys=keys, keys_units=keys_units,
                       sound=sound, start_s=0.0 if clip is None else max(clip[0], 0.0)) as exports:
        from puppet.loop import Pipeline, run_frames  # the solver's native module: only here

        with Pipeline(rig, render=False, iterations=iterations, precompute=precompute) as pipeline:
            def on_frame(solved) -> None:
                exports.write(solved)
                if progress is not None:
                    progress(exports.frames, len(frames))

            run_frames(pipeline, frames, on_frame=on_frame)
    exports.report.seconds = time.monotonic() - start
    return exports.report


def take_frames(rig, reader, fps: float, clip=None, layers=None) -> Playback:
    """The frames of a take for ``rig``'s servos (the take checked against the rig first);
    clip: (in_s, out_s, loop) of a segment, or None; layers: a layered take's
    ``LayerOptions`` (None: as recorded)."""
    fps = check_fps(fps)
    ids = [int(i) for i in rig.servo_map.ids]
    if len(reader) == 0:
        raise ExportError(reader.path, "the take holds no readings")
    reader.check_rig(ids, dict(rig.servo_map.models), rig_name=rig.name)
    frames = Playback.of_take(reader, ids, fps=fps, rig=rig, layers=layers)
    if clip is None:
        return frames
    in_s, out_s, loop = clip

    def joint_rotations(ticks):
        return rig.skeleton.joint_rotations(rig.servo_map.angles(ticks.astype(np.int32)))

    return frames.clip(in_s, out_s, loop=loop, joint_rotations=joint_rotations)


PC2_HEADER_BYTES = 32
BVH_BYTES_PER_CHANNEL = 10  # a channel's value as BVH text, with its separator


VIDEO_BYTES_PER_PIXEL = 0.25
"""What an H.264 frame of the renderer's pictures is taken to cost, per pixel (a sixth of the raw
yuv420p frame; the character on a plain ground at VideoSink's quality encodes to far less): a
bound for the size rule, not a prediction."""

PNG_BYTES_PER_PIXEL = 1.0
"""What a PNG frame of the renderer's pictures is taken to cost, per pixel (a third of the raw
RGB frame; the character on a plain ground compresses to far less): a bound for the size rule of
``--frames FOLDER``, not a prediction."""


def estimated_bytes(fmt: str, frames: int, vertices: int = 0, joints: int = 0,
                    pixels: int = 0) -> int:
    """About how many bytes an export of ``frames`` frames writes (exact for PC2: a header and
    3 float32 per vertex per frame; USD: the points alone, 3 float32 per vertex per frame;
    glTF: a key time and a rotation, translation and scale per joint per frame before key
    reduction; BVH: six channels of text per joint per frame; mp4: ``pixels`` (width × height)
    at VIDEO_BYTES_PER_PIXEL per frame; png: a folder of PNG frames, ``pixels`` at
    PNG_BYTES_PER_PIXEL per frame). Checked against ``puppet.limits.EXPORT_BYTES`` before
    anything is written (``check_size``)."""
    if fmt == "mp4":
        return int(frames * pixels * VIDEO_BYTES_PER_PIXEL)
    if fmt == "png":
        return int(frames * pixels * PNG_BYTES_PER_PIXEL)
    if fmt == "pc2":
        return PC2_HEADER_BYTES + frames * vertices * 12
    if fmt == "usd":
        return frames * vertices * 12
    if fmt == "gltf":
        return frames * (4 + joints * (16 + 12 + 12))
    return frames * joints * 6 * BVH_BYTES_PER_CHANNEL


def check_size(target, what: str, size: int, made_of: str, force: bool, option: str = "--fps") -> None:
    """Refuse (ExportError naming ``target``) an output of about ``size`` bytes over
    ``puppet.limits.EXPORT_BYTES`` unless ``force``, before anything is written. what: the output
    in words ("the --pc2 output"); made_of: what the size comes from, in words; option: the
    option that makes it smaller."""
    if size > limits.EXPORT_BYTES.hi and not force:
        raise ExportError(target, f"{what} would be about {_bytes(size)} ({made_of}), over the "
                                  f"{_bytes(limits.EXPORT_BYTES.hi)} an export writes without "
                                  f"--force (puppet.limits.EXPORT_BYTES); lower {option}, or "
                                  "pass --force to write it")


def _bytes(n: float) -> str:
    """A byte count in words: 2.0 TB, 16.0 GiB, 512 MB."""
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} bytes"


class ExportWriters:
    """Every format asked in ``outputs``, written one solved frame at a time.

    A context manager: making it checks the outputs, entering opens a temporary file per format;
    ``write(pipeline)`` after each solve adds that frame (deformed mesh V' = M T, joint
    transforms) to every file; a clean exit closes the files and renames them into place and
    fills ``report``; an exception removes them (an existing good file is kept).

    rig, reader: the rig solved on and the take (TakeReader, its path: the take is an input no
    output may overwrite). frames: the Playback the frames come from (its fps, count, cuts).
    up, space, influences, meters_per_unit, keys, keys_units, sound: as export_take; start_s: the
    take time of the files' frame 1 (a clip's in point: its sound offset and timecode move on by
    it, ``puppet.export.sync``). Fields: report
    (ExportReport), frames (written so far), sync (``puppet.export.sync.sync_fields``: the take's
    sound and start timecode, written into the glTF, USD and BVH).
    """

    def __init__(self, rig, reader, outputs: Outputs, frames: Playback, *, up: str = "y",
                 space: str = "object", influences: int = 4, meters_per_unit: float = 1.0,
                 keys: float | None = None, keys_units: float | None = None, sound=None,
                 start_s: float = 0.0):
        if up not in UP_AXES:
            raise ExportError("--up", f"up axis must be one of {UP_AXES}, got {up!r}")
        self.to_space = point_space(rig, space)
        items = outputs.items()
        if not items:
            raise ExportError("export", "nothing to write: give --gltf, --usd, --pc2 and/or --bvh FILE")
        self.keys_deg, self.keys_units = _key_tolerances(rig, outputs, keys, keys_units)
        from puppet.replay import take_inputs

        metadata = getattr(reader, "metadata", None)
        sound = sound if sound is not None else getattr(metadata, "sound", None)
        # the sound is an input too (at its stored path, or the --sound file given)
        self.inputs = take_inputs(reader.path, rig, sound)
        self.force = outputs.force
        check_distinct({f"--{fmt}": target for fmt, target in items})
        for fmt, target in items:
            check_output(target, kind=KINDS[fmt], inputs=self.inputs, force=self.force,
                         what=f"--{fmt} output")
            if fmt in SUFFIXES and target.suffix.lower() not in SUFFIXES[fmt]:
                raise ExportError(target, f"--{fmt} files are named *{' or *'.join(SUFFIXES[fmt])}")
        self.order = SourceOrder(rig)
        for fmt, target in items:  # before anything is written: a size no one meant
            size = estimated_bytes(fmt, len(frames), self.order.n_out, rig.skeleton.bone_count)
            check_size(target, f"the --{fmt} output", size,
                       f"{len(frames)} frames at {frames.fps:g} fps, {self.order.n_out} vertices, "
                       f"{rig.skeleton.bone_count} joints", self.force)
        if "bvh" in dict(items):
            self._bvh_offsets, self._end_sites = _bvh_skeleton(rig)
        self.rig, self.items, self.targets = rig, items, dict(items)
        self.up, self.influences, self.meters_per_unit = up, influences, meters_per_unit
        self.fps = frames.fps
        self.sync = sync_fields(frames.fps, sound, getattr(metadata, "timecode", None), start_s)
        self.key_frames = frames.key_frames()  # a shot's key poses: glTF keys whatever --keys
        self.report = ExportReport(frames=len(frames), fps=frames.fps, cuts=list(frames.cuts),
                                   take_seconds=(frames.t_ns[-1] - frames.t_ns[0]) * 1e-9)
        if "pc2" in self.targets:
            self.report.pc2_space = space
        if rig.source is not None and any(f in self.targets for f in ("gltf", "usd")):
            self.report.warnings += rig.source.warnings
        self.report.warnings += frames.notes  # a clip ended at the take's end
        self.writers: dict[str, object] = {}
        self.frames = 0
        self._stack = contextlib.ExitStack()
        self._buffers = None

    def __enter__(self) -> "ExportWriters":
        rig, sk, order, fps = self.rig, self.rig.skeleton, self.order, self.fps
        V_out = order.take(rig.V)
        self._bvh_names, bvh_renamed = safe_names(sk.names, "bvh")
        self.renamed = {"bvh": bvh_renamed} if bvh_renamed and "bvh" in self.targets else {}
        stack = self._stack.__enter__()
        try:
            for fmt, target in self.items:
                temporary = stack.enter_context(atomic_output(
                    target, kind=KINDS[fmt], inputs=self.inputs, force=self.force,
                    what=f"--{fmt} output"))
                with _blame(target, fmt):
                    if fmt == "gltf":
                        self.writers[fmt] = GltfWriter(temporary, names=sk.names, parents=sk.parents,
                                                       heads=sk.heads, frames=sk.frames, V=V_out,
                                                       F=order.F, W=order.take(rig.W), fps=fps,
                                                       influences=self.influences, name=rig.name,
                                                       keys_deg=self.keys_deg,
                                                       keys_units=self.keys_units,
                                                       source=rig.source,
                                                       forced_frames=self.key_frames,
                                                       sync=self.sync)
                    elif fmt == "usd":
                        from puppet.export.usd import UsdWriter

                        self.writers[fmt] = UsdWriter(temporary, names=sk.names, parents=sk.parents,
                                                      heads=sk.heads, frames=sk.frames, V=V_out,
                                                      F=order.F, fps=fps, name=rig.name,
                                                      meters_per_unit=self.meters_per_unit,
                                                      source=rig.source, weld=order.index,
                                                      textures=target.with_name(
                                                          f"{target.stem}_textures"),
                                                      inputs=self.inputs, sync=self.sync)
                        if self.writers[fmt].renamed:
                            self.renamed["usd"] = dict(self.writers[fmt].renamed)
                    elif fmt == "pc2":
                        self.writers[fmt] = Pc2Writer(temporary, order.n_out,
                                                      start_frame=float(FIRST_FRAME), sample_rate=1.0)
                    else:
                        self.writers[fmt] = BvhWriter(temporary, names=self._bvh_names,
                                                      parents=sk.parents, offsets=self._bvh_offsets,
                                                      end_sites=self._end_sites,
                                                      frame_time=1.0 / fps, positions="all",
                                                      sync=self.sync)
        except BaseException:
            self.__exit__(*sys.exc_info())
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            try:
                for fmt, writer in self.writers.items():  # complete files, then the renames
                    with _blame(self.targets[fmt], fmt):
                        writer.close()
            except BaseException:
                self._stack.__exit__(*sys.exc_info())
                raise
            self._stack.__exit__(None, None, None)
            self._finish()
            return False
        for writer in self.writers.values():
            _abort(writer)
        return bool(self._stack.__exit__(exc_type, exc, tb))

    def _finish(self) -> None:
        report = self.report
        report.frames = self.frames
        for fmt, target in self.items:
            report.files[fmt] = (target, target.stat().st_size)
        for writer in self.writers.values():
            report.warnings += getattr(writer, "warnings", [])
        report.renamed = self.renamed
        rig = self.rig
        diagonal = float(np.linalg.norm(rig.V.max(0) - rig.V.min(0))) or 1.0
        if "gltf" in self.writers:
            b = self._buffers
            count = max(b["count"], 1) if b else 1
            report.lbs_rms_pct = 100.0 * float(np.sqrt((b["squares"] if b else 0.0) / count)) / diagonal
            report.lbs_max_pct = 100.0 * (b["worst"] if b else 0.0) / diagonal
            if self.keys_deg is not None:
                joints = self.writers["gltf"].keys_kept
                kept = sum(sum(c.values()) for c in joints.values())
                every = 2 * len(joints) * self.frames
                report.keys = {"rotation_deg": self.keys_deg, "translation_units": self.keys_units,
                               "kept": kept, "every_frame": every,
                               "kept_pct": 100.0 * kept / max(every, 1), "joints": joints,
                               "key_poses": len(self.key_frames)}
        if "bvh" in self.writers:
            report.bvh_stretch_max_pct = 100.0 * (self._buffers["drift"] if self._buffers else 0.0) / diagonal

    def _allocate(self, pipeline) -> dict:
        """The per-frame arrays, made once on the first frame (their shapes need the model)."""
        rig, order = self.rig, self.order
        sk = rig.skeleton
        parents = sk.parents
        need_mesh = any(f in self.writers for f in ("gltf", "usd", "pc2"))
        return {
            "T": np.empty(pipeline.T.shape, np.float64),
            "deformed": np.empty((len(rig.V), 3)),
            "points": np.empty((order.n_out, 3)),
            "pc2_points": np.empty((order.n_out, 3), np.float32),
            "in_space": np.empty((order.n_out, 3)),
            "joints": JointTransforms(sk.heads),
            "rotations": np.empty((sk.bone_count, 3, 3)),
            "offsets": sk.heads - np.where(parents[:, None] >= 0, sk.heads[parents], 0.0),
            "chain": np.empty((sk.bone_count, 3)),
            "local": np.empty((sk.bone_count, 3)),
            "M": pipeline.model.lbs_matrix() if need_mesh else None,  # (n, 4m) float64: V' = M T
            "skinned": np.empty((order.n_out, 3)),
            "squares": 0.0, "count": 0, "worst": 0.0, "drift": 0.0,
        }

    def write(self, pipeline) -> None:
        """Add the frame just solved in ``pipeline`` (its T) to every file."""
        if self._buffers is None:
            self._buffers = self._allocate(pipeline)
        b = self._buffers
        targets, order, up = self.targets, self.order, self.up
        parents = self.rig.skeleton.parents
        gltf, usd, pc2, bvh = (self.writers.get(f) for f in FORMATS)
        joints, points = b["joints"], b["points"]
        joints.update(pipeline.T)
        if b["M"] is not None:
            b["T"][...] = pipeline.T
            np.matmul(b["M"], b["T"], out=b["deformed"])
            order.take(b["deformed"], out=points)
        if pc2 is not None:
            pc2_points, cache = b["pc2_points"], points
            if self.to_space is not None:  # into the mesh object's local space
                cache = b["in_space"]
                np.matmul(points, self.to_space[:, :3].T, out=cache)
                cache += self.to_space[:, 3]
            if up == "z":
                pc2_points[:, 0] = cache[:, 0]
                pc2_points[:, 1] = -cache[:, 2]
                pc2_points[:, 2] = cache[:, 1]
            else:
                pc2_points[...] = cache
            with _blame(targets["pc2"], "pc2"):
                pc2.write(pc2_points)
        if usd is not None:
            with _blame(targets["usd"], "usd"):
                usd.write(points, joints.world)
        if gltf is not None:
            skinned = b["skinned"]
            gltf.write(joints.world)
            gltf.skin(gltf.written, out=skinned)  # what the file's keys reproduce
            skinned -= points
            error = np.sqrt(np.einsum("ij,ij->i", skinned, skinned))
            b["squares"] += float(np.dot(error, error))
            b["count"] += len(error)
            b["worst"] = max(b["worst"], float(error.max()))
        if bvh is not None:
            rotations, local, chain, offsets = b["rotations"], b["local"], b["chain"], b["offsets"]
            R, c = joints.rotation, joints.pivot
            rotations[...] = R
            local[...] = c
            has = parents >= 0
            Rp = np.swapaxes(R[parents[has]], 1, 2)
            rotations[has] = Rp @ R[has]                                   # parent-relative
            local[has] = np.einsum("bij,bj->bi", Rp, c[has] - c[parents[has]])  # in parent frame
            for j, p in enumerate(parents):  # what a BVH reader rebuilds: rest offsets, no stretch
                chain[j] = c[j] if p < 0 else chain[p] + R[p] @ offsets[j]
            b["drift"] = max(b["drift"], float(np.linalg.norm(chain - c, axis=1).max()))
            with _blame(targets["bvh"], "bvh"):
                bvh.write(rotations, positions=local)
        self.frames += 1
