"""What a batch will do: the takes (patterns expanded), each take's output files, resume.

A take ``session/take01.mcap`` writes ``OUT/take01.<ext>`` for every asked format (FORMATS):
mp4 as ``puppet play --out``, the others as ``puppet export``; and its log, ``OUT/take01.log``. Everything here runs in the
driver before any work starts, so bad input fails fast and names what is wrong.
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass
from pathlib import Path

from puppet.atomic import check_folder_output, check_output
from puppet.batch.errors import BatchError

FORMATS = ("mp4", "gltf", "usd", "pc2", "bvh")
SUFFIXES = {"mp4": ".mp4", "gltf": ".glb", "usd": ".usdc", "pc2": ".pc2", "bvh": ".bvh"}
KINDS = {"mp4": "video", "gltf": "glb", "usd": "usd", "pc2": "pc2", "bvh": "bvh"}  # puppet.atomic
DEFAULT_FORMATS = ("gltf", "usd", "pc2", "bvh")
TAKE_SUFFIX = ".mcap"
LOG_SUFFIX = ".log"


@dataclass(frozen=True)
class Job:
    """One take = one task. take: the take file; outputs: {format: final path} in OUT; log: the
    take's log file in OUT (its row, warnings, errors and the engine's lines for it)."""

    take: Path
    outputs: dict[str, Path]
    log: Path

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


def expand_takes(patterns: list[str] | tuple[str, ...]) -> list[Path]:
    """Take files from arguments: files, folders (their *.mcap) and glob patterns, sorted within
    each argument, duplicates dropped. BatchError if an argument matches nothing at all."""
    takes: list[Path] = []
    seen: set[Path] = set()
    if not patterns:
        raise BatchError("no takes given: name take files, folders or patterns (session/*.mcap)")
    for pattern in patterns:
        path = Path(pattern)
        if path.is_dir():
            found = sorted(path.glob(f"*{TAKE_SUFFIX}"))
        elif path.exists():
            found = [path]
        elif glob.has_magic(pattern):
            found = sorted(Path(p) for p in glob.glob(pattern) if Path(p).is_file())
        else:
            raise BatchError(f"{pattern}: no such take file")
        if not found:
            raise BatchError(f"{pattern}: no takes matched")
        for take in found:
            key = take.resolve()
            if key not in seen:
                seen.add(key)
                takes.append(take)
    return takes


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


def plan_jobs(takes: list[Path], out: Path, formats: tuple[str, ...],
              inputs: list[Path], *, force: bool = False) -> list[Job]:
    """One Job per take; BatchError if two takes share a name (same output files), OutputError
    if an output breaks ``puppet.atomic``'s rule (one of the inputs: a take, a rig file; a
    device; another kind of file without ``force``)."""
    jobs: list[Job] = []
    by_name: dict[str, Path] = {}
    all_inputs = list(takes) + list(inputs)
    for take in takes:
        other = by_name.setdefault(take.stem, take)
        if other != take:
            raise BatchError(f"{take}: same name as {other}: both would write {out / take.stem}.*; "
                             "rename one or run them in two batches")
        outputs = {fmt: out / f"{take.stem}{SUFFIXES[fmt]}" for fmt in formats}
        log = out / f"{take.stem}{LOG_SUFFIX}"
        for fmt, target in outputs.items():
            check_output(target, kind=KINDS[fmt], inputs=all_inputs, force=force)
        check_output(log, kind="text", inputs=all_inputs, force=force, what="log file")
        jobs.append(Job(take, outputs, log))
    return jobs


def is_done(job: Job, inputs: list[Path]) -> bool:
    """True when every output exists and is newer than the take and every rig file.

    Outputs are renamed into place only when whole (atomic), so one that exists is complete."""
    try:
        newest_input = max(os.stat(p).st_mtime_ns for p in [job.take, *inputs])
        return all(os.stat(p).st_mtime_ns > newest_input for p in job.outputs.values())
    except FileNotFoundError:
        return False
