"""What a batch will do: the takes (patterns expanded), each take's files, each take's rig.

A take ``session/take01.mcap`` writes ``OUT/take01.<ext>`` for every asked format (FORMATS):
mp4 as ``puppet play --out``, the others as ``puppet export``; its log ``OUT/take01.log`` and
its manifest ``OUT/take01.batch.json`` (``puppet.batch.manifest``). Takes found in folders below
the folder an argument names (``shoot/*/*.mcap``) write into the same folders below OUT, so
takes of one name in different folders do not collide; two of one name that would still
write the same files (``a/take.mcap b/take.mcap``) are refused before any work, naming both.

The rig a take is solved on is never a guess (``RigFinder``, the rule of ``puppet export``):
without ``--rig``, the rig the take stores (its rig file's text, its character found where
the rig file was, next to the take or, for the built-in rig's takes, among the built-in
files); with ``--rig``, that rig, refused for a take of other servos naming both rig files.

Everything here runs in the driver before any work starts, so bad input fails fast and names
what is wrong; a take whose rig cannot be found is a failed row naming its rig file.
"""

from __future__ import annotations

import glob
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from puppet.atomic import check_folder_output, check_output
from puppet.batch.errors import BatchError
from puppet.batch.manifest import MANIFEST_SUFFIX
from puppet.checksum import bytes_sha256, file_sha256
from puppet.rig import Rig
from puppet.rig.checksum import character_sha256

FORMATS = ("mp4", "gltf", "usd", "pc2", "bvh")
SUFFIXES = {"mp4": ".mp4", "gltf": ".glb", "usd": ".usdc", "pc2": ".pc2", "bvh": ".bvh"}
KINDS = {"mp4": "video", "gltf": "glb", "usd": "usd", "pc2": "pc2", "bvh": "bvh"}  # puppet.atomic
DEFAULT_FORMATS = ("gltf", "usd", "pc2", "bvh")
TAKE_SUFFIX = ".mcap"
LOG_SUFFIX = ".log"


@dataclass(frozen=True)
class Job:
    """One take = one task.

    take: the take file; outputs: {format: final path} in OUT; log: the take's log file (its
    row, warnings, errors and the engine's lines for it); manifest: what its outputs were made
    from (``puppet.batch.manifest``); rig_key: which of the batch's rigs it is solved on
    (``TakeRig.key``; "" before the rig is found)."""

    take: Path
    outputs: dict[str, Path]
    log: Path
    manifest: Path
    rig_key: str = ""

    @property
    def name(self) -> str:
        return self.take.stem


def parse_formats(text: str | tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """('gltf', 'pc2', ...) from 'gltf,pc2' (order kept, repeats dropped); BatchError if unknown."""
    items = text.split(",") if isinstance(text, str) else list(text)
    formats: list[str] = []
    for item in (i.strip().lower() for i in items):
        if not item:
            continue
        if item not in FORMATS:
            raise BatchError(f"--formats: unknown format {item!r} (known: {', '.join(FORMATS)})")
        if item not in formats:
            formats.append(item)
    if not formats:
        raise BatchError(f"--formats: no format given (known: {', '.join(FORMATS)})")
    return tuple(formats)


def expand_takes(patterns: list[str] | tuple[str, ...],
                 base: Path | None = None) -> list[tuple[Path, Path]]:
    """(take, base) for every take file the arguments name: files (base: their folder), folders
    (their *.mcap; base: the folder) and glob patterns (``**`` spans folders; base: the
    pattern's leading folders without a wildcard); ``base`` given: every take's base (a
    session's takes/ folder: outputs mirror its shots). Sorted within each argument, duplicates
    dropped. BatchError if an argument matches nothing at all. Outputs mirror each take's folder
    below its base (``plan_jobs``)."""
    takes: list[tuple[Path, Path]] = []
    seen: set[Path] = set()
    given = base
    if not patterns:
        raise BatchError("no takes given: name take files, folders or patterns (session/*.mcap)")
    for pattern in patterns:
        path = Path(pattern)
        if path.is_dir():
            found, base = sorted(path.glob(f"*{TAKE_SUFFIX}")), path
        elif path.exists():
            found, base = [path], path.parent
        elif glob.has_magic(pattern):
            found = sorted(Path(p) for p in glob.glob(pattern, recursive=True) if Path(p).is_file())
            base = _fixed_folder(pattern)
        else:
            raise BatchError(f"{pattern}: no such take file")
        if not found:
            raise BatchError(f"{pattern}: no takes matched")
        for take in found:
            key = take.resolve()
            if key not in seen:
                seen.add(key)
                takes.append((take, given if given is not None else base))
    return takes


def _fixed_folder(pattern: str) -> Path:
    """The leading folders of a glob pattern up to the first part with a wildcard."""
    parts = Path(pattern).parts
    fixed = []
    for part in parts[:-1]:
        if glob.has_magic(part):
            break
        fixed.append(part)
    return Path(*fixed) if fixed else Path(".")


def prepare_out(out: str | os.PathLike) -> Path:
    """The output folder, created if missing; BatchError unless a file can be made in it."""
    folder = check_folder_output(out, what="output folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BatchError(f"{folder}: cannot create the output folder: {err.strerror or err}") from None
    if not folder.is_dir():
        raise BatchError(f"{folder}: the output folder is not a folder")
    probe = folder / f".puppet-batch-probe.{os.getpid()}"
    try:
        probe.write_bytes(b"")
    except OSError as err:
        raise BatchError(f"{folder}: the output folder cannot be written: "
                         f"{err.strerror or err}") from None
    probe.unlink(missing_ok=True)
    return folder


def plan_jobs(takes: list[tuple[Path, Path]], out: Path, formats: tuple[str, ...],
              inputs: list[Path], *, force: bool = False, dry_run: bool = False) -> list[Job]:
    """One Job per (take, base) of ``expand_takes``: its files go to ``OUT/<its folder below
    base>/<take name>.<ext>`` (folders made here unless ``dry_run``). BatchError naming both
    takes if two would still write the same files (two take files of one name, named one by
    one); OutputError if an output breaks ``puppet.atomic``'s rule (one of the inputs: a take, a
    rig file; a device; another kind of file without ``force``)."""
    by_stem: dict[Path, Path] = {}
    all_inputs = [take for take, _ in takes] + list(inputs)
    for take, base in takes:  # every name first: a collision is refused before any folder
        stem = out / _below(take.parent, base) / take.stem
        other = by_stem.setdefault(stem, take)
        if other != take:
            raise BatchError(f"{take}: same name as {other}: both would write {stem}.*; name "
                             "their folders with one pattern (shoot/*/*.mcap: outputs mirror "
                             "the folders), rename one, or run them in two batches")
    jobs: list[Job] = []
    for stem, take in by_stem.items():
        folder = stem.parent
        if not dry_run:
            _make_folder(folder, out)
        outputs = {fmt: folder / f"{take.stem}{SUFFIXES[fmt]}" for fmt in formats}
        job = Job(take, outputs, folder / f"{take.stem}{LOG_SUFFIX}",
                  folder / f"{take.stem}{MANIFEST_SUFFIX}")
        if folder.is_dir():  # a dry run's folder yet to be made holds nothing to refuse
            for fmt, target in outputs.items():
                check_output(target, kind=KINDS[fmt], inputs=all_inputs, force=force)
            check_output(job.log, kind="text", inputs=all_inputs, force=force, what="log file")
            check_output(job.manifest, kind="text", inputs=all_inputs, force=force,
                         what="manifest")
        jobs.append(job)
    return jobs


def _below(folder: Path, base: Path) -> Path:
    """folder relative to base (both as given or absolute); '.' when it is not below it."""
    relative = Path(os.path.relpath(folder.resolve(), base.resolve()))
    return Path(".") if relative.parts[:1] == ("..",) else relative


def _make_folder(folder: Path, out: Path) -> None:
    """Make a folder below OUT for mirrored takes; BatchError naming it when it cannot be."""
    if folder.exists() and not folder.is_dir():
        raise BatchError(f"{folder}: exists in the output folder {out} and is not a folder; "
                         "it is where takes of that folder write")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BatchError(f"{folder}: cannot create this folder of the output folder {out}: "
                         f"{err.strerror or err}") from None


@dataclass(frozen=True)
class TakeRig:
    """The rig one or more takes are solved on.

    key: rig_sha256 and character (takes with equal keys share one rig and one precompute);
    rig: the loaded rig (uncalibrated: each take applies its own recorded calibration to a
    copy); file: the rig file in words (the --rig file, or the file the take was recorded
    with); rig_sha256: the rig's text (the --rig file's bytes, or the rig map the take stores);
    character: ``puppet.rig.checksum.character_sha256``."""

    key: str
    rig: Rig
    file: str
    rig_sha256: str
    character: str


class RigFinder:
    """Finds each take's rig, loading each distinct rig once.

    given: the --rig rig (None: every take's own); a take's own rig is the one ``puppet
    export`` would use without --rig (``puppet.replay.rig_from_take``)."""

    def __init__(self, given: Rig | None = None):
        self.given = None if given is None else self._rig(given, _rig_file(given),
                                                          _rig_text_sha256(given))
        self._loaded: dict[tuple, TakeRig] = {}

    def for_take(self, take: Path) -> TakeRig:
        """The take's rig; TakeError / RigError naming the take and the rig file(s) when the
        take is not a regular file or cannot be read, its rig is neither found nor given, or
        the given rig does not fit it."""
        from puppet.replay import recorded_rig_file, rig_from_take
        from puppet.take import TakeError, TakeReader
        from puppet.take.reader import check_take_rig

        if not stat.S_ISREG(os.stat(take).st_mode):  # a FIFO would block the driver
            raise TakeError(take, "not a regular file (a folder, FIFO or device): a take is an "
                                  "MCAP file")
        meta = TakeReader(take).metadata
        recorded = recorded_rig_file(meta)
        if self.given is not None:
            rig = self.given.rig
            try:
                check_take_rig(meta, ids=[int(i) for i in rig.servo_map.ids],
                               models=dict(rig.servo_map.models), rig_name=rig.name, path=take)
            except TakeError as err:
                raise TakeError(take, f"{err.reason}; recorded with rig file "
                                      f"{recorded or '(not stored)'}, given --rig "
                                      f"{self.given.file}") from None
            return self.given
        key = (meta.rig_map_text, meta.rig_name, take.resolve().parent)
        if key not in self._loaded:
            rig = rig_from_take(take, meta)
            text = meta.rig_map_text or _builtin_text()
            self._loaded[key] = self._rig(rig, recorded or str(rig.path), bytes_sha256(text))
        return self._loaded[key]

    def rigs(self) -> list[TakeRig]:
        """Every distinct rig found so far."""
        found = {} if self.given is None else {self.given.key: self.given}
        for take_rig in self._loaded.values():
            found.setdefault(take_rig.key, take_rig)
        return list(found.values())

    @staticmethod
    def _rig(rig: Rig, file: str, rig_sha256: str) -> TakeRig:
        character = character_sha256(rig)
        return TakeRig(f"{rig_sha256[:16]}-{character[:16]}", rig, file, rig_sha256, character)


def _rig_file(rig: Rig) -> str:
    return str(rig.path) if rig.path is not None else f"(rig {rig.name!r} made in memory)"


def _rig_text_sha256(rig: Rig) -> str:
    """sha256 of the rig file's bytes and of its calibration file's (its zero ticks shape a take
    that recorded none); of its name for a rig made in memory."""
    if rig.path is None or not Path(rig.path).is_file():
        return bytes_sha256(f"rig {rig.name}")
    calibration = getattr(rig.calibration, "path", None)
    if calibration is None or not Path(calibration).is_file():
        return file_sha256(rig.path)
    return bytes_sha256(file_sha256(rig.path) + file_sha256(calibration))


def _builtin_text() -> str:
    """The built-in rig file's text (a take of the built-in rig may store no rig map)."""
    from puppet.rig.load import BUILTIN_RIG

    return BUILTIN_RIG.read_text(encoding="utf-8")
