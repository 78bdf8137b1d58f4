"""``puppet rig …``: inspect rigs."""

from __future__ import annotations

import json
import time

import click


@click.group()
def rig() -> None:
    """Inspect rigs."""


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
    info = {"name": loaded.name, "path": str(loaded.path) if loaded.path else None, "vertices": len(loaded.V), "triangles": len(loaded.F),
            "bones": loaded.skeleton.bone_count, "servos": len(loaded.servo_map),
            "full": kinds["full"], "relative": kinds["relative"], "free": kinds["free"],
            "weights_ok": report.ok, "load_s": round(load_s, 4)}
    if as_json:
        click.echo(json.dumps(info))
        return
    click.echo(f"rig        {loaded.name} ({loaded.path or 'built-in'})")
    click.echo(f"vertices   {info['vertices']}")
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
