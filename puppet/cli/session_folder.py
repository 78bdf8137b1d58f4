"""``puppet session``: a studio session folder from the terminal (scripts, tests): list it, make
and rename shots, note, circle, lock, delete, restore takes, cut segments. Each command opens
the session as its one writer (refused while a studio holds it), changes one thing, and ends."""

from __future__ import annotations

import json
from contextlib import contextmanager

import click

from puppet import limits
from puppet.cli.common import InRange

_TAKE = InRange(limits.TAKE_NUMBER)


@click.group("session")
def session() -> None:
    """A studio session folder: shots, numbered takes, marks, trash (plain files, one writer).

    \b
    Examples:
      puppet session shot shoot "walk"           make shoot/ if new; new shot, the current one
      puppet session list shoot                  every shot and take, circled, locked, missing
      puppet session circle shoot walk 2
      puppet session note shoot walk 2 "nice arc on the tail"
      puppet session lock shoot walk 2           read-only: no edit, no delete
      puppet session delete shoot walk 1         into shoot/trash/ (restore brings it back)
      puppet session segment shoot walk 2 step 0.5 2.0 --loop
      puppet batch shoot --circled --formats gltf    exports into shoot/exports/
    """


@contextmanager
def _writer(folder: str, create: bool = False):
    from puppet.studio import SessionWriter

    with SessionWriter.open(folder, create=create) as writer:
        for note in writer.notes:
            click.echo(f"warning: {note}", err=True)
        yield writer


def _said(writer, shot: str, take) -> None:
    marks = [f for f, on in (("circled", take.circled), ("locked", take.locked),
                             ("in the trash", take.trashed)) if on]
    click.echo(f"shot {writer.shot(shot).name!r} take {take.number}: "
               f"{', '.join(marks) or 'not circled, not locked'}")


@session.command("list")
@click.argument("folder")
@click.option("--json", "as_json", is_flag=True, help="Print the listing as one JSON object.")
def list_(folder: str, as_json: bool) -> None:
    """Every shot and take of the session (read only: works while a studio runs)."""
    from puppet.studio import SessionFolder

    found = SessionFolder.read(folder)
    if as_json:
        click.echo(json.dumps(found.listing()))
        return
    for note in found.notes:
        click.echo(f"warning: {note}", err=True)
    click.echo(found.table())


@session.command()
@click.argument("folder")
@click.argument("name")
def shot(folder: str, name: str) -> None:
    """A new shot NAME, the one new recordings go to (the session is made if new)."""
    with _writer(folder, create=True) as writer:
        made = writer.new_shot(name)
        click.echo(f"shot {made.name!r}: takes in {writer.folder / 'takes' / made.key}")


@session.command()
@click.argument("folder")
@click.argument("shot_name", metavar="SHOT")
def use(folder: str, shot_name: str) -> None:
    """Make SHOT the one new recordings go to."""
    with _writer(folder) as writer:
        click.echo(f"shot {writer.use_shot(shot_name).name!r} is the current shot")


@session.command()
@click.argument("folder")
@click.argument("shot_name", metavar="SHOT")
@click.argument("name")
def rename(folder: str, shot_name: str, name: str) -> None:
    """Call SHOT NAME from now on (its folder keeps its name)."""
    with _writer(folder) as writer:
        click.echo(f"shot {writer.rename_shot(shot_name, name).name!r}")


@session.command()
@click.argument("folder")
@click.argument("shot_name", metavar="SHOT")
@click.argument("take", type=_TAKE)
@click.argument("text")
def note(folder: str, shot_name: str, take: int, text: str) -> None:
    """Set a take's note ("" clears it)."""
    with _writer(folder) as writer:
        writer.note(shot_name, take, text)
        click.echo(f"shot {writer.shot(shot_name).name!r} take {take}: note {text!r}")


def _mark(name: str, method: str, doc: str):
    @session.command(name, help=doc)
    @click.argument("folder")
    @click.argument("shot_name", metavar="SHOT")
    @click.argument("take", type=_TAKE)
    @click.option("--off", is_flag=True, help="Take the mark off.")
    def command(folder: str, shot_name: str, take: int, off: bool) -> None:
        with _writer(folder) as writer:
            _said(writer, shot_name, getattr(writer, method)(shot_name, take, not off))

    return command


_mark("circle", "circle", "Circle a take (a good one); --off uncircles it.")
_mark("lock", "lock_take", "Lock a take (read-only: no note, circle, segment or delete); --off "
                           "unlocks it.")


@session.command()
@click.argument("folder")
@click.argument("shot_name", metavar="SHOT")
@click.argument("take", type=_TAKE)
def delete(folder: str, shot_name: str, take: int) -> None:
    """Move a take into the session's trash (restorable)."""
    with _writer(folder) as writer:
        _said(writer, shot_name, writer.delete(shot_name, take))


@session.command()
@click.argument("folder")
@click.argument("shot_name", metavar="SHOT")
@click.argument("take", type=_TAKE)
def restore(folder: str, shot_name: str, take: int) -> None:
    """Bring a take back from the session's trash."""
    with _writer(folder) as writer:
        _said(writer, shot_name, writer.restore(shot_name, take))


@session.command()
@click.argument("folder")
@click.argument("shot_name", metavar="SHOT")
@click.argument("take", type=_TAKE)
@click.argument("name")
@click.argument("in_s", metavar="[IN", type=InRange(limits.SECONDS_FROM_START), required=False)
@click.argument("out_s", metavar="OUT]", type=InRange(limits.SECONDS_FROM_START), required=False)
@click.option("--loop", is_flag=True, help="The clip plays as a loop (its seam blended).")
@click.option("--remove", is_flag=True, help="Remove the segment NAME instead (no IN OUT).")
def segment(folder: str, shot_name: str, take: int, name: str, in_s: float | None,
            out_s: float | None, loop: bool, remove: bool) -> None:
    """A named clip of a take from IN to OUT seconds (0 = its first reading)."""
    if remove != (in_s is None and out_s is None) or (in_s is None) != (out_s is None):
        raise click.UsageError("give IN and OUT (seconds) to add a segment, neither with --remove")
    with _writer(folder) as writer:
        if remove:
            writer.remove_segment(shot_name, take, name)
            click.echo(f"segment {name!r} removed")
            return
        made = writer.add_segment(shot_name, take, name, in_s, out_s, loop=loop)
        click.echo(f"segment {made.name!r}: {made.in_s:g} s to {made.out_s:g} s"
                   + (", loop" if made.loop else ""))


COMMANDS = (session,)
