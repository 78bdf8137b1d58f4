"""``puppet batch``: re-solve and re-export many takes, on this machine or on a Ray cluster."""

from __future__ import annotations

import json
import sys

import click

from puppet import limits
from puppet.cli.common import (InRange, force_option, keys_option, keys_units_option,
                               layer_options, load_rig, rig_files, space_option)

EXIT_DONE = 0       # every take done (or up to date with --resume)
EXIT_SETUP = 1      # nothing done: a setup error (`Error: ...`: an option, the takes, --out, Ray)
EXIT_FAILED = 3     # some takes failed or timed out (their rows say why); the others are written
# cancelled by SIGINT or SIGTERM: 128 + the signal's number (130, 143), as a shell reports it


@click.command()
@click.argument("takes", nargs=-1)
@click.option("--out", "out", default=None,
              help="Output folder (created): OUT/<take>.<ext>, a log OUT/<take>.log and a "
                   "manifest OUT/<take>.batch.json per take; takes in folders below the one an "
                   "argument names (shoot/*/*.mcap) go to the same folders below OUT. Required, "
                   "but for a session folder: its exports/ (exports/<shot>/take003.glb).")
@click.option("--circled", is_flag=True,
              help="With a session folder: only its circled takes [default: every take not in "
                   "its trash].")
@click.option("--rig", "rig_path", default=None,
              help="Rig to solve every take on (a take of other servos is refused) [default: "
                   "each take's own, as puppet export].")
@click.option("--formats", default="gltf,usd,pc2,bvh", show_default=True,
              help="Comma-separated, of mp4 (as puppet play), gltf, usd, pc2, bvh (as puppet "
                   "export).")
@click.option("--fps", default=None,
              help=f"Frames per second of every output ({limits.FPS}) [default: 30; a session "
                   "folder's: the rate its takes were recorded at, when they agree].")
@click.option("--size", nargs=2, type=InRange(limits.FRAME_SIZE), default=(640, 480),
              show_default=True, metavar="W H",
              help=f"Video size in pixels (mp4), each {limits.FRAME_SIZE}.")
@click.option("--up", type=click.Choice(["y", "z"]), default="y", show_default=True,
              help="Up axis of the PC2 points: z for Blender's Mesh Cache.")
@space_option
@keys_option
@keys_units_option
@click.option("--engine", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="local: a process pool on this machine; ray: Ray tasks (pip install "
                   "'puppet[ray]').")
@click.option("--address", default=None,
              help="Ray cluster to run on (host:6379, ray://host:10001, or auto: the one "
                   "running here); default: a private Ray started for this batch. An address "
                   "that is not a Ray head fails within 10 s.")
@click.option("--workers", type=InRange(limits.WORKERS), default=None,
              help=f"Worker processes (local), CPUs of a private Ray, or tasks at once on a "
                   f"cluster ({limits.WORKERS}) [default: cores].")
@click.option("--retries", type=InRange(limits.RETRIES), default=2, show_default=True,
              help="Tries after the first of a take whose worker died (killed, out of memory).")
@click.option("--take-timeout", "take_timeout", type=InRange(limits.SECONDS), default=None,
              metavar="SECONDS",
              help="Fail a take that runs longer and free its worker [default: 120 s + 60 s "
                   "per second of take].")
@click.option("--resume", is_flag=True,
              help="Skip takes whose manifest says their outputs are up to date (same take, rig, "
                   "character, settings and puppet version, outputs unchanged); each redone "
                   "take's row says why.")
@click.option("--dry-run", is_flag=True,
              help="Print what would be done for each take and why; write nothing.")
@layer_options(strict=False)
@click.option("--json", "as_json", is_flag=True, help="Print the report as one JSON line.")
@force_option
def batch(takes: tuple[str, ...], out: str | None, circled: bool, rig_path: str | None,
          formats: str, fps: str, size: tuple[int, int], up: str, space: str, keys: float | None,
          keys_units: float | None,
          engine: str, address: str | None, workers: int | None, retries: int,
          take_timeout: float | None, resume: bool, dry_run: bool, as_json: bool,
          force: bool, layers) -> None:
    """Solve and write every take; a failed take is reported and the others go on.

    Exit status: 0 all done; 1 nothing done (setup error); 3 some takes failed or timed out
    (with --dry-run: would fail);
    130 / 143 cancelled by SIGINT (Ctrl-C) / SIGTERM: every worker stopped, staging removed,
    the summary so far printed.

    \b
    Examples:
      puppet batch SESSION --circled --formats gltf     a studio session's circled takes
      puppet batch session/*.mcap --out exports/ --formats gltf,usd
      puppet batch session/ --out videos/ --formats mp4 --size 1280 720 --resume
      puppet batch 'shoot/*/*.mcap' --out exports/ --fps 24 --resume --dry-run
      puppet batch session/*.mcap --out exports/ --engine ray --address 10.0.0.5:6379
    """
    from puppet.batch import BatchCancelled, BatchError, run_batch
    from puppet.studio import is_session
    from puppet.studio.exports import batch_input

    if not takes:
        raise BatchError("no takes given: name take files, folders or patterns (session/*.mcap)")
    base = None
    if any(is_session(t) for t in takes):  # a studio's session folder: its takes, its exports/
        if len(takes) > 1:
            raise BatchError(f"{takes[0]}: a session folder is batched alone (given with "
                             f"{len(takes) - 1} other argument(s))")
        chosen = batch_input(takes[0], circled=circled)
        for note in chosen.notes:
            click.echo(f"warning: {note}", err=True)
        takes, base, out = tuple(map(str, chosen.takes)), chosen.base, out or str(chosen.out)
        if fps is None and chosen.fps is not None:  # a 24 fps shot exports at 24
            fps = f"{chosen.fps:g}"
    elif circled:
        raise BatchError(f"--circled: picks a session folder's circled takes; {takes[0]} is not "
                         "a session folder (no session.json, no takes/)")
    if out is None:
        raise BatchError("--out: missing (only a session folder has a default: its exports/)")
    fps = "30" if fps is None else fps
    rig = None if rig_path is None else load_rig(rig_path)
    bar = None
    total = finished = 0
    lines = not sys.stderr.isatty()  # a log, not a terminal: one line per finished take

    def on_start(count: int) -> None:
        nonlocal bar, total
        total = count
        if not lines:
            bar = click.progressbar(length=count, label="takes", file=sys.stderr)
            bar.__enter__()

    def on_result(result) -> None:
        nonlocal finished
        finished += 1
        if lines:
            click.echo(result.progress_line(finished, total), err=True)
        else:
            bar.update(1)
        for warning in result.warnings:  # e.g. a damaged take, or gaps cut: where a user looks
            click.echo(f"{'' if lines else chr(10)}warning: {result.take}: {warning}", err=True)

    try:
        report = run_batch(list(takes), out, rig=rig,
                           rig_inputs=rig_files(rig) if rig is not None else [],
                           formats=formats, fps=fps, up=up, space=space, size=size, keys=keys,
                           keys_units=keys_units, engine=engine,
                           workers=workers, address=address, resume=resume, dry_run=dry_run,
                           force=force, retries=retries, take_timeout=take_timeout,
                           on_start=on_start, on_result=on_result, base=base, layers=layers)
    except BatchCancelled as stop:
        if bar is not None:
            bar.__exit__(None, None, None)
            bar = None
        report = stop.report
        click.echo(json.dumps(report.as_dict()) if as_json else report.table())
        click.echo(f"cancelled by {stop.signal_name}: every worker stopped, staging removed",
                   err=True)
        raise click.exceptions.Exit(stop.exit_status) from None
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    click.echo(json.dumps(report.as_dict()) if as_json else report.table())
    if report.failed:
        failed = click.ClickException(
            f"{len(report.failed)} of {len(report.rows)} takes would fail (see the table); "
            "nothing written" if dry_run else f"{len(report.failed)} of {len(report.rows)} takes "
            "failed (see the table); the others are written")
        failed.exit_code = EXIT_FAILED
        raise failed


COMMANDS = (batch,)
