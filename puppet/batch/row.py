"""One take's row of a batch: what happened to it, where, how long, what it wrote, and why.

Workers fill a row while they run a take (``task.run_take``); engines set ``retries`` and the
end states they decide (a cancelled or timed-out take); the driver sets ``skipped`` rows, the
final output paths and the log file, and prints rows as the summary table, ``--json`` and one
progress line each. The same row is written, with the take's warnings and errors and the
engine's lines for it, to the take's log file in the output folder (``log_text``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

DONE, SKIPPED, FAILED, CANCELLED, TIMED_OUT = "done", "skipped", "failed", "cancelled", "timed out"
STATES = (DONE, SKIPPED, FAILED, CANCELLED, TIMED_OUT)
"""Every state a row ends in: done (outputs written), skipped (``--resume``: outputs up to
date), failed (the reason says why; its outputs untouched), cancelled (SIGINT/SIGTERM before or
while it ran), timed out (ran past ``--take-timeout``)."""

TO_DO = "to do"
"""The state of a row in a dry run (``--dry-run``) for a take that would be made; its reason
says why (new, or what changed). A dry run's other rows are skipped and failed (refused)."""

UNFINISHED = (FAILED, CANCELLED, TIMED_OUT)
"""States of a take whose outputs were not written."""

MAX_LOG_LINES = 2000
"""Bound of ``TakeResult.log_lines``: the engine's lines kept per take (the first ones and a
note of how many more were dropped)."""

_COLOUR = re.compile(r"\x1b\[[0-9;?]*[ -/]*[@-~]")


def plain(line: str) -> str:
    """A log line without terminal colour and cursor codes (ANSI CSI sequences) or its newline."""
    return _COLOUR.sub("", line).rstrip("\r\n")


@dataclass
class TakeResult:
    """What happened to one take.

    take:        the take file, as given.
    state:       one of STATES.
    reason:      why, in words: the error of a failed take, what changed for a redone one
                 ("fps 30 -> 24"), "up to date" for a skipped one; "" when nothing to say.
    frames:      frames written per file (exports; else the video's).
    seconds:     wall time of the take in its worker (s); 0 when skipped.
    cpu_seconds: CPU time of the worker process on the take (s), all tries.
    worker:      "host:pid" that ran it ("" when it never ran).
    retries:     tries after the first (a dead worker's take, a Ray task re-run).
    files:       {format: path}: in the worker, the finished file in its staging folder; in the
                 report, the file in the output folder.
    data:        {format: bytes} when a remote worker sends its files back (Ray); None after.
    warnings:    the take's warnings (a damaged take's recovery report, gaps cut, what of the
                 character file its exports could not carry).
    notes:       the exports' report, as ``puppet export`` prints it (frames, keys kept per
                 joint, fits), its file paths the final ones once the driver moved them.
    log_lines:   the engine's own lines for this take (colour codes removed), MAX_LOG_LINES.
    log:         path of the take's log file in the output folder ("" before it is written).
    """

    take: str
    state: str = DONE
    reason: str = ""
    frames: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    worker: str = ""
    retries: int = 0
    files: dict[str, str] = field(default_factory=dict)
    data: dict[str, bytes] | None = None
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    log_lines: list[str] = field(default_factory=list)
    log: str = ""

    @classmethod
    def failed(cls, take, reason: str, state: str = FAILED, **fields) -> "TakeResult":
        """A row for a take that did not finish: failed (default), cancelled or timed out."""
        return cls(take=str(take), state=state, reason=reason, **fields)

    def fail(self, reason: str, state: str = FAILED) -> None:
        """Mark this take unfinished (its outputs are not written)."""
        self.state, self.reason = state, reason

    @property
    def error(self) -> str | None:
        """Why the take did not finish; None when it did (done or skipped)."""
        return self.reason if self.state in UNFINISHED else None

    @property
    def attempts(self) -> int:
        """Tries it took: 1 + retries."""
        return 1 + self.retries

    def add_report(self, report) -> None:
        """Keep an export's report (``puppet.export.ExportReport``): its text as notes, its
        warnings as the take's."""
        self.notes.extend(report.text().splitlines())
        self.warnings.extend(w for w in report.warnings if w not in self.warnings)

    def moved(self, source: str, target: str) -> None:
        """A file of this take moved from ``source`` (the worker's) to ``target``: said so in
        the notes."""
        self.notes = [note.replace(source, target) for note in self.notes]

    def add_log(self, line: str) -> None:
        """Keep one of the engine's lines for this take (colour codes removed; bounded)."""
        if len(self.log_lines) < MAX_LOG_LINES:
            self.log_lines.append(plain(line))
        elif len(self.log_lines) == MAX_LOG_LINES:
            self.log_lines.append(f"(more lines dropped: {MAX_LOG_LINES} kept)")

    def as_dict(self) -> dict:
        """The row as ``--json`` shows it (output paths, not format names)."""
        return {"take": self.take, "state": self.state, "reason": self.reason,
                "worker": self.worker, "cpu_s": round(self.cpu_seconds, 3),
                "wall_s": round(self.seconds, 3), "retries": self.retries,
                "frames": self.frames, "outputs": [self.files[f] for f in sorted(self.files)],
                "warnings": list(self.warnings), "log": self.log}

    def progress_line(self, index: int, total: int) -> str:
        """One line for a finished take: '[3/8] take02.mcap done 1.2 s on host:123 (reason)'."""
        line = f"[{index}/{total}] {self.take} {self.state}"
        if self.worker:
            line += f" {self.seconds:.1f} s on {self.worker}"
        if self.retries:
            line += f" after {self.retries} {'retry' if self.retries == 1 else 'retries'}"
        return line + (f": {self.reason}" if self.reason else "")

    def log_text(self) -> str:
        """The take's log file: its row, warnings, errors and the engine's lines for it."""
        lines = [f"take: {self.take}", f"state: {self.state}"]
        if self.reason:
            lines.append(f"reason: {self.reason}")
        lines += [f"worker: {self.worker or '-'}", f"wall: {self.seconds:.3f} s",
                  f"cpu: {self.cpu_seconds:.3f} s", f"retries: {self.retries}",
                  f"frames: {self.frames}"]
        lines += [f"output: {self.files[f]}" for f in sorted(self.files)]
        lines += [f"warning: {w}" for w in self.warnings]
        if self.error is not None:
            lines.append(f"error: {self.error}")
        if self.notes:
            lines.append("export report:")
            lines += [f"  {note}" for note in self.notes]
        if self.log_lines:
            lines.append("engine:")
            lines += [f"  {line}" for line in self.log_lines]
        return "\n".join(lines) + "\n"

    def short_outputs(self, folder: Path) -> str:
        """Output paths relative to the output folder, for the summary table."""
        names = []
        for fmt in sorted(self.files):
            path = Path(self.files[fmt])
            try:
                names.append(str(path.relative_to(folder)))
            except ValueError:
                names.append(str(path))
        return " ".join(names) or "-"
