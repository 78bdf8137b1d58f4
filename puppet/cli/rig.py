"""``puppet rig …``: inspect rigs."""

from __future__ import annotations

import json
import sys
import time

import click

from puppet import limits
from puppet.cli.common import InRange, fail, force_option, rig_files


@click.group()
def rig() -> None:
    """Start, inspect and check rigs."""


@rig.command("init")
@click.argument("character")
@click.option("--out", default=None, help="Rig file to write (default: CHARACTER with .toml).")
@click.option("--skin", type=InRange(limits.SKIN_INDEX), default=None,
              help="Which glTF skin, when the file has several (0, 1, ...).")
@click.option("--force", is_flag=True, help="Overwrite an existing rig file.")
def rig_init(character: str, out: str | None, skin: int | None, force: bool) -> None:
    """Write a starting rig file from a skinned glTF character.

    Every joint with its parent and its rest axes in the character's words, a suggested fixed
    root, solver options sized to the mesh, and one commented [[servo]] block per joint to fill.

    \b
    Example:
      puppet rig init creature.glb --out creature.toml
    """
    from puppet.rig.init_file import write_rig_init

    path, loaded = write_rig_init(character, out, skin=skin, force=force)
    for name in loaded.unused_joints:
        click.echo(f"warning: {character}: joint {name!r} influences no vertex; the rig file holds it "
                   "fixed (the solve cannot place a bone that moves nothing)", err=True)
    click.echo(f"rig file: {path} ({loaded.skeleton.bone_count} joints, {len(loaded.V)} vertices, "
               f"{loaded.file_vertices} in the file)")


@rig.command("axes")
@click.argument("rig_path")
@click.option("--out", default="axes.png", show_default=True, help="Contact sheet (PNG) to write.")
@click.option("--all", "every_joint", is_flag=True, help="Also joints without a servo, about x, y and z.")
@click.option("--angle", default=30.0, show_default=True, type=InRange(limits.ANGLE_DEG),
              help=f"Turn shown each way ({limits.ANGLE_DEG}).")
@click.option("--from", "first", default=1, show_default=True, type=InRange(limits.AXES_FROM),
              help="Show the turns from this one on (1 = the first): the next sheet of a model "
                   "with more turns than one sheet holds.")
@force_option
def rig_axes(rig_path: str, out: str, every_joint: bool, angle: float, force: bool,
             first: int) -> None:
    """Render each servo's joint turned -ANGLE and +ANGLE: pick axis and sign by looking.

    One pair of panels per servo (per joint axis with --all), the positive side framed green,
    each pair seen along its turn's axis and framed on what the joint moves, with the axis, an
    arrow the way it turns and the turn in rig init's words.
    A rig without [[servo]] blocks yet (fresh from `rig init`) shows every joint, as --all.
    One sheet holds at most 120 pairs (puppet.render.axes_sheet.MAX_PAIRS; servos first): a
    model of many joints shows the first ones (--from N: the next sheet), says how many it left
    out, and its progress; Ctrl-C ends it and writes nothing.

    \b
    Example:
      puppet rig axes creature.toml --out sheet.png --all
    """
    from puppet.rig import load_rig
    from puppet.rig.axis_turns import axis_turns
    from puppet.atomic import check_output
    from puppet.render.axes_sheet import MAX_PAIRS, Turn, render_turn_sheet, save_sheet

    loaded = load_rig(rig_path)
    inputs = [rig_path, *rig_files(loaded)]
    check_output(out, kind="png", inputs=inputs, force=force, what="axes sheet")  # before rendering
    if not every_joint and len(loaded.servo_map) == 0:
        click.echo(f"{rig_path}: no [[servo]] blocks yet: showing every joint about x, y and z "
                   "(as --all); fill in a block's joint and axis to see just its servo", err=True)
        every_joint = True
    turns = [Turn(*t) for t in axis_turns(loaded, every_joint)]
    total = len(turns)
    if first > total:
        fail(f"--from {first}: {rig_path} has {total} turns to show")
    turns = turns[first - 1:]
    if first > 1 or len(turns) > MAX_PAIRS:
        last = first - 1 + min(len(turns), MAX_PAIRS)
        rest = total - last
        click.echo(f"warning: {total} turns to show; one sheet holds {MAX_PAIRS} pairs "
                   f"(puppet.render.axes_sheet.MAX_PAIRS): showing turns {first} to {last} "
                   f"(servos first), {total - (last - first + 1)} left out"
                   + (f"; --from {last + 1} shows the next ones, or give the joints you mean "
                      "servos and run it without --all" if rest else ""), err=True)
        turns = turns[:MAX_PAIRS]
    sk = loaded.skeleton
    # a pair's two renders take a moment on a CPU renderer: a sheet of many shows its progress
    # (Ctrl-C ends it, nothing written)
    with click.progressbar(length=len(turns), label="axes sheet", file=sys.stderr) as bar:
        done = [0]

        def on_pair(pairs: int) -> None:
            bar.update(pairs - done[0])
            done[0] = pairs

        sheet = render_turn_sheet(loaded.V, loaded.F, loaded.W, sk.heads, sk.tails, sk.parents,
                                  turns, angle_deg=angle, on_pair=on_pair)
    path = save_sheet(sheet, out, inputs=inputs, force=force)
    click.echo(f"axes sheet: {path} ({len(sheet.panels)} panels: {len(turns)} pairs of -{angle:g}° and "
               f"+{angle:g}°, the positive side framed green)")


@rig.command("info")
@click.argument("rig_path", required=False)
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def rig_info(rig_path: str | None, as_json: bool) -> None:
    """Vertices, bones, servos and constraint kinds of a rig (built-in when omitted).

    The first line names the rig's file: the built-in critter's rig file is a complete example
    to copy, and what ``hw-sim --rig`` serves.
    """
    from puppet.rig import builtin, load_rig

    start = time.perf_counter()
    loaded = builtin() if rig_path is None else load_rig(rig_path)
    load_s = time.perf_counter() - start
    kinds = loaded.bone_kinds()
    report = loaded.check_weights()
    file_vertices = len(loaded.V) if loaded.source_index is None else len(loaded.source_index)
    info = {"name": loaded.name, "path": str(loaded.path) if loaded.path else None,
            "vertices": len(loaded.V), "file_vertices": file_vertices,
            "triangles": len(loaded.F),
            "bones": loaded.skeleton.bone_count, "servos": len(loaded.servo_map),
            "full": kinds["full"], "relative": kinds["relative"], "free": kinds["free"],
            "weights_ok": report.ok, "load_s": round(load_s, 4)}
    if as_json:
        click.echo(json.dumps(info))
        return
    click.echo(f"rig        {loaded.name} ({loaded.path or 'built-in'})")
    click.echo(f"vertices   {info['vertices']} (file: {file_vertices}, before welding seams)")
    click.echo(f"triangles  {info['triangles']}")
    click.echo(f"bones      {info['bones']}")
    click.echo(f"servos     {info['servos']}: " + ", ".join(
        f"{s.id}:{s.model}->{s.joint}" for s in loaded.servo_map.servos))
    for kind in ("full", "relative", "free"):
        click.echo(f"{kind:<10} {', '.join(kinds[kind]) or '-'}")
    click.echo(f"pins       {len(loaded.pins)}")
    opts = loaded.solver_options
    click.echo(f"solver     clusters={opts.clusters} extra_weights={opts.extra_weights} energy={opts.energy}")
    click.echo(f"weights    {report.summary()}")
    click.echo(f"load       {load_s:.3f} s")
    anchor = loaded.anchor_problem()
    if anchor is not None:  # a bare character (.glb/.npz): a rig file must fix this
        click.echo(f"warning: {anchor}", err=True)


COMMANDS = (rig,)
