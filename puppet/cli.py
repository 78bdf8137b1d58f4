"""The puppet command line. Nothing imports this module; it imports the parts it runs."""

from __future__ import annotations

import sys

import click


def _not_built(name: str, issue: int) -> None:
    click.echo(f"puppet {name}: not built yet (issue #{issue}).", err=True)
    sys.exit(1)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="puppet")
def main() -> None:
    """Turn a posed puppet of Dynamixel servos into rendered character animation.

    \b
    Examples:
      puppet demo                          built-in character on a simulated bus
      puppet rig info --json               check the built-in rig
      puppet live --rig my.toml --port /dev/ttyUSB0 --out take.mp4
      puppet play take.mcap --out take.mp4
    """


@main.command()
@click.option("--out", default="demo.mp4", show_default=True, help="Video file to write.")
@click.option("--seconds", default=10.0, show_default=True, help="Length of the run.")
def demo(out: str, seconds: float) -> None:
    """Run the live loop on the built-in character and a simulated bus."""
    _not_built("demo", 8)


@main.command()
@click.option("--rig", "rig_path", required=True, help="Rig servo map (TOML).")
@click.option("--port", required=True, help="Serial port, e.g. /dev/ttyUSB0.")
@click.option("--record", "take_path", default=None, help="Also record a take here.")
@click.option("--out", default=None, help="Video file to write.")
@click.option("--frames", default=None, help="Folder for PNG frames.")
def live(rig_path: str, port: str, take_path: str | None, out: str | None, frames: str | None) -> None:
    """Read the puppet, solve and render live."""
    _not_built("live", 8)


@main.command()
@click.option("--rig", "rig_path", required=True, help="Rig servo map (TOML).")
@click.option("--port", required=True, help="Serial port.")
@click.option("--out", required=True, help="Take file to write (.mcap).")
def record(rig_path: str, port: str, out: str) -> None:
    """Record a take (raw servo readings) without rendering."""
    _not_built("record", 8)


@main.command()
@click.argument("take")
@click.option("--rig", "rig_path", default=None, help="Rig to replay on (default: the take's).")
@click.option("--out", required=True, help="Video file to write.")
@click.option("--speed", default=1.0, show_default=True, help="Playback speed factor.")
def play(take: str, rig_path: str | None, out: str, speed: float) -> None:
    """Replay a take through the solver and renderer."""
    _not_built("play", 8)


@main.command()
@click.option("--port", required=True, help="Serial port.")
def scan(port: str) -> None:
    """List the servos on a bus: ids, models, firmware."""
    _not_built("scan", 8)


@main.command()
@click.option("--rig", "rig_path", required=True, help="Rig servo map (TOML).")
@click.option("--port", required=True, help="Serial port.")
def calibrate(rig_path: str, port: str) -> None:
    """Capture the zero pose into the rig's calibration file."""
    _not_built("calibrate", 8)


@main.command()
@click.argument("take")
@click.option("--pc2", default=None, help="Point cache of the deformed mesh.")
@click.option("--bvh", default=None, help="Sensed joint rotations as BVH.")
def export(take: str, pc2: str | None, bvh: str | None) -> None:
    """Export a take as a mesh point cache and a BVH skeleton."""
    _not_built("export", 8)


@main.group()
def rig() -> None:
    """Inspect rigs."""


@rig.command("info")
@click.argument("rig_path", required=False)
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def rig_info(rig_path: str | None, as_json: bool) -> None:
    """Vertices, bones, servos and constraint kinds of a rig (built-in when omitted)."""
    import json
    import time

    from puppet.rig import RigError, builtin, load_rig

    start = time.perf_counter()
    try:
        loaded = builtin() if rig_path is None else load_rig(rig_path)
    except RigError as err:
        raise click.ClickException(str(err)) from None
    load_s = time.perf_counter() - start
    kinds = loaded.bone_kinds()
    report = loaded.check_weights()
    info = {"name": loaded.name, "vertices": len(loaded.V), "triangles": len(loaded.F),
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


if __name__ == "__main__":
    main()
