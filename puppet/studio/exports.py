"""A session folder as the input of an export or a batch: which takes, where outputs go.

``puppet batch SESSION [--circled]`` batches the session's takes (every take not in the trash,
or only the circled ones); outputs go to SESSION/exports/ unless told otherwise, mirroring the
shots' folders (exports/<shot>/take003.glb), so take 3 of two shots never collide. A shot
exports at the frame rate its takes were recorded at (``recorded_fps``: ``puppet studio --fps``,
their start timecode's) unless told otherwise.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from puppet.studio import layout
from puppet.studio.errors import StudioError
from puppet.studio.folder import SessionFolder


@dataclass(frozen=True)
class BatchInput:
    """takes: the take files, in shot then number order; base: the folder outputs mirror
    below (SESSION/takes); out: SESSION/exports; notes: what reading the session said (a
    rebuilt index, missing takes skipped), for warnings; fps: the rate the takes were
    recorded at (``recorded_fps``), None when they do not agree or do not say."""

    takes: list[Path]
    base: Path
    out: Path
    notes: list[str]
    fps: float | None = None


def recorded_fps(paths) -> float | None:
    """The frame rate the takes at ``paths`` were recorded at (their start timecode's) when
    they all say the same one: a 24 fps shot exports at 24 unless told otherwise; None when
    they disagree or one says none (the export's default)."""
    from puppet.take import TakeReader

    rates = set()
    for path in paths:
        timecode = TakeReader(path).metadata.timecode
        rates.add(None if timecode is None else float(timecode.rate.fps))
    return rates.pop() if len(rates) == 1 else None


def batch_input(folder: str | os.PathLike, *, circled: bool = False) -> BatchInput:
    """The takes of session ``folder`` to batch; StudioError naming the folder when it holds
    none (none circled, with ``circled``)."""
    session = SessionFolder.read(folder)
    chosen, missing = session.chosen(circled=circled)
    if not chosen:
        which = "circled takes" if circled else "takes outside the trash"
        hint = (" (circle one: puppet session circle SESSION SHOT TAKE)" if circled else "")
        raise StudioError(f"{session.folder}: no {which} to batch{hint}"
                          + (f"; {'; '.join(missing)}" if missing else ""))
    takes = [path for _, _, path in chosen]
    return BatchInput(takes, session.folder / layout.TAKES, session.folder / layout.EXPORTS,
                      [*session.notes, *missing], recorded_fps(takes))
